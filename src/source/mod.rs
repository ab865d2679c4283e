//! Video sources for playback: video files, network streams, screens and GStreamer pipelines
//! ([`media`]), still images, slideshows, raw frames on a pipe or FIFO, V4L2 cameras
//! ([`crate::camera`]) and generated test patterns (spellings in [`spec::HELP`]), and the
//! [`Feed`] that runs a source on its own thread so decoding never blocks the render loop.
//!
//! Frames are 8-bit RGBA, sRGB-encoded as stored ([`ContentFrame`], content pixels).

pub mod feed;
pub mod media;
pub mod pattern;
pub mod playlist;
pub mod spec;
#[cfg(target_os = "linux")]
pub mod v4l2;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

pub use feed::{Feed, FeedMode, FeedStats, Poll};
pub use media::AudioOut;
pub use playlist::{Playlist, PlaylistItem};
pub use spec::{HELP, MediaSpec, Pattern, RawFormat, ScreenSpec, SourceSpec};

use crate::error::{Error, Result};
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// What a source delivers next.
pub enum Next {
    /// A new frame; `wait` is how long the source wants it on screen before its next one
    /// (slideshows, paced patterns); `None` = deliver the next as soon as it is available.
    Frame {
        frame: ContentFrame,
        wait: Option<Duration>,
    },
    /// Nothing yet (a stream reconnecting, a paused film): ask again. It lets the feed's
    /// thread notice that it was stopped.
    Idle,
    /// No more frames.
    End,
}

/// A video source. `next` may block (reading a pipe, waiting for a camera).
pub trait VideoSource: Send {
    /// For messages: what is being played.
    fn describe(&self) -> String;
    /// What may block before the first frame (a FIFO's open waits for its writer), run on the
    /// source's own thread before any `next`; nothing by default.
    fn prepare(&mut self) -> Result<()> {
        Ok(())
    }
    /// The next frame, or the end.
    fn next(&mut self) -> Result<Next>;
    /// Whether playback should end when the source ends (streams), rather than hold the last
    /// frame (still images).
    fn ends_playback(&self) -> bool;
    /// Told once before `prepare`: whether frames are shown in real time (the newest wins) or
    /// offline (every frame, as fast as they come). Media paced by a clock uses it.
    fn set_live(&mut self, live: bool) {
        let _ = live;
    }
    /// A handle to pause, resume and seek the media and read its counts (media sources only).
    fn control(&self) -> Option<crate::media::Control> {
        None
    }
}

/// How long [`check`] lets media take to show that it plays (its first frame prerolled).
pub const MEDIA_CHECK_TIMEOUT: Duration = Duration::from_secs(10);

/// Opens the source a spec names, media with its sound to the default audio sink.
pub fn open(spec: &SourceSpec) -> Result<Box<dyn VideoSource>> {
    open_with(spec, &AudioOut::default())
}

/// Opens the source a spec names; media plays its sound as `audio` says.
pub fn open_with(spec: &SourceSpec, audio: &AudioOut) -> Result<Box<dyn VideoSource>> {
    match spec {
        SourceSpec::Media(m) => Ok(Box::new(media::MediaSource::new(m, audio.clone())?)),
        SourceSpec::Image(path) => Ok(Box::new(Still {
            path: path.clone(),
            frame: Some(read_image(path)?),
        })),
        SourceSpec::Folder { dir, period } => Ok(Box::new(Slideshow::new(dir, *period)?)),
        SourceSpec::Raw { path, size, format } => {
            let (reader, name): (RawInput, String) = match path {
                None => (
                    RawInput::Open(Box::new(std::io::stdin())),
                    "standard input".into(),
                ),
                // Opened by the first frame, on the source's own thread: a FIFO's open waits for
                // its writer.
                Some(p) => (RawInput::Closed(p.clone()), p.display().to_string()),
            };
            Ok(Box::new(Raw {
                reader,
                name,
                size: *size,
                format: *format,
                frames: 0,
            }))
        }
        #[cfg(target_os = "linux")]
        SourceSpec::V4l2 { device, size } => {
            Ok(Box::new(crate::camera::V4l2Camera::open(device, *size)?))
        }
        #[cfg(not(target_os = "linux"))]
        SourceSpec::V4l2 { .. } => Err(Error::Input("V4L2 sources exist only on Linux".into())),
        SourceSpec::Pattern {
            pattern,
            size,
            fps,
            frames,
        } => Ok(Box::new(pattern::Generator::new(
            *pattern, *size, *fps, *frames,
        ))),
    }
}

/// Whether `spec` names a source that can be played, without starting it: a still image is
/// decoded, and so is the first image of a folder that decodes; a raw source's file, FIFO or device and a
/// camera's device must exist (neither is opened: a FIFO's open waits for its writer, and a
/// frame read here would be lost to the playback). The service checks a `play` request with
/// it before the picture that is on stops. Media is brought to its first frame and stopped,
/// within [`MEDIA_CHECK_TIMEOUT`].
pub fn check(spec: &SourceSpec) -> Result<()> {
    let exists = |p: &Path, what: &str| match std::fs::metadata(p) {
        Ok(m) if m.is_dir() => Err(Error::Input(format!(
            "{}: a folder, not {what}",
            p.display()
        ))),
        Ok(_) => Ok(()),
        Err(e) => Err(Error::io(p, "look up", e)),
    };
    match spec {
        SourceSpec::Media(m) => media::check(m, MEDIA_CHECK_TIMEOUT),
        SourceSpec::Image(path) => read_image(path).map(|_| ()),
        // As the show plays it: past images that do not decode, to the first that does.
        SourceSpec::Folder { dir, period } => Slideshow::new(dir, *period)?.next().map(|_| ()),
        SourceSpec::Raw { path: Some(p), .. } => {
            exists(p, "a raw source")?;
            // Readable by this process, asked without opening it (a FIFO's open would wait).
            let c = std::ffi::CString::new(p.as_os_str().as_encoded_bytes())
                .map_err(|_| Error::Input(format!("{}: a path with a NUL byte", p.display())))?;
            // SAFETY: `c` is a valid NUL-terminated path; faccessat only reads it.
            let rc = unsafe {
                libc::faccessat(libc::AT_FDCWD, c.as_ptr(), libc::R_OK, libc::AT_EACCESS)
            };
            if rc != 0 {
                return Err(Error::Input(format!(
                    "{}: this user cannot read it ({}); a raw source must be readable",
                    p.display(),
                    std::io::Error::last_os_error()
                )));
            }
            Ok(())
        }
        SourceSpec::Raw { path: None, .. } | SourceSpec::Pattern { .. } => Ok(()),
        #[cfg(target_os = "linux")]
        SourceSpec::V4l2 { device, .. } => exists(device, "a V4L2 device"),
        #[cfg(not(target_os = "linux"))]
        SourceSpec::V4l2 { .. } => Err(Error::Input("V4L2 sources exist only on Linux".into())),
    }
}

/// Decodes a PNG or JPEG file to an RGBA frame.
pub fn read_image(path: &Path) -> Result<ContentFrame> {
    let bytes = crate::files::read_regular(
        path,
        "an image (PNG or JPEG)",
        crate::files::MAX_IMAGE_BYTES,
    )?;
    let img = image::load_from_memory(&bytes)
        .map_err(|e| Error::Input(format!("{}: not a readable image ({e})", path.display())))?;
    let rgba = img.to_rgba8();
    let (w, h) = rgba.dimensions();
    ContentFrame::from_rgba(w as usize, h as usize, rgba.into_raw())
}

/// One image, then held.
struct Still {
    path: PathBuf,
    frame: Option<ContentFrame>,
}

impl VideoSource for Still {
    fn describe(&self) -> String {
        format!("image {}", self.path.display())
    }
    fn next(&mut self) -> Result<Next> {
        Ok(match self.frame.take() {
            Some(frame) => Next::Frame { frame, wait: None },
            None => Next::End,
        })
    }
    fn ends_playback(&self) -> bool {
        false
    }
}

/// The images of a folder in name order, each for `period`, looping.
struct Slideshow {
    dir: PathBuf,
    files: Vec<PathBuf>,
    period: Duration,
    index: usize,
    /// The images skipped so far (each is warned of once).
    skipped: std::collections::HashSet<usize>,
}

const IMAGE_EXTENSIONS: &[&str] = &["png", "jpg", "jpeg"];

impl Slideshow {
    fn new(dir: &Path, period: Duration) -> Result<Self> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| Error::io(dir, "list folder", e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.is_file()
                    && p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                        IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str())
                    })
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(Error::Input(format!(
                "{}: no PNG or JPEG images in this folder",
                dir.display()
            )));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            files,
            period,
            index: 0,
            skipped: Default::default(),
        })
    }
}

impl VideoSource for Slideshow {
    fn describe(&self) -> String {
        format!(
            "slideshow of {} image(s) in {}, {:.1} s each",
            self.files.len(),
            self.dir.display(),
            self.period.as_secs_f64()
        )
    }
    /// The next image that decodes: one that does not (damaged, or changed since the folder
    /// was listed) is skipped with a warning, so one bad file does not stop the show; an error
    /// only when none of them does.
    fn next(&mut self) -> Result<Next> {
        let mut last = None;
        for _ in 0..self.files.len() {
            let k = self.index % self.files.len();
            self.index += 1;
            match read_image(&self.files[k]) {
                Ok(frame) => {
                    return Ok(Next::Frame {
                        frame,
                        wait: Some(self.period),
                    });
                }
                Err(e) => {
                    if self.skipped.insert(k) {
                        tracing::warn!("slideshow: skipping {}: {e}", self.files[k].display());
                    }
                    last = Some(e);
                }
            }
        }
        Err(last
            .unwrap_or_else(|| Error::Input(format!("{}: no images to show", self.dir.display()))))
    }
    fn ends_playback(&self) -> bool {
        false
    }
}

/// Where a [`Raw`] source reads from.
enum RawInput {
    /// A file, FIFO or device, not opened yet.
    Closed(PathBuf),
    Open(Box<dyn Read + Send>),
}

/// Raw 8-bit frames back to back on a pipe, a FIFO or in a file.
struct Raw {
    reader: RawInput,
    name: String,
    size: ImageSize,
    format: RawFormat,
    frames: u64,
}

impl VideoSource for Raw {
    fn describe(&self) -> String {
        format!(
            "raw {:?} {} frames from {}",
            self.format, self.size, self.name
        )
    }

    fn prepare(&mut self) -> Result<()> {
        if let RawInput::Closed(p) = &self.reader {
            let file = std::fs::File::open(p).map_err(|e| Error::io(p, "open raw source", e))?;
            self.reader = RawInput::Open(Box::new(file));
        }
        Ok(())
    }

    fn next(&mut self) -> Result<Next> {
        let ImageSize {
            width: w,
            height: h,
        } = self.size;
        let len = w * h * self.format.bytes_per_pixel();
        self.prepare()?;
        let RawInput::Open(reader) = &mut self.reader else {
            return Ok(Next::End);
        };
        let mut buf = vec![0u8; len];
        let mut got = 0;
        while got < len {
            match reader.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(Error::Io {
                        path: PathBuf::from(&self.name),
                        op: "read raw frames",
                        source: e,
                    });
                }
            }
        }
        if got == 0 {
            return Ok(Next::End);
        }
        if got < len {
            return Err(Error::Input(format!(
                "raw source {}: the stream ended {got} bytes into frame {} of {len} bytes \
                 ({w}x{h} {:?}); check ?size= and &format= against what the producer writes",
                self.name,
                self.frames + 1,
                self.format
            )));
        }
        self.frames += 1;
        let frame = match self.format {
            RawFormat::Rgb24 => ContentFrame::from_rgb(w, h, &buf)?,
            RawFormat::Rgba => ContentFrame::from_rgba(w, h, buf)?,
        };
        Ok(Next::Frame { frame, wait: None })
    }

    fn ends_playback(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2×1 PNG of one grey level.
    fn png(level: u8) -> Vec<u8> {
        let mut out = Vec::new();
        image::RgbImage::from_pixel(2, 1, image::Rgb([level; 3]))
            .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    #[test]
    fn a_slideshow_skips_a_damaged_image_and_check_reads_what_play_would() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.png"), dir.path().join("b.png"));
        std::fs::write(&a, &png(10)[..20]).unwrap();
        std::fs::write(&b, png(200)).unwrap();
        let spec = SourceSpec::Folder {
            dir: dir.path().to_path_buf(),
            period: Duration::from_secs(1),
        };
        // The first image is the damaged one: `check`, as the show, goes on past it to the good
        // one, and the show shows that one again and again.
        check(&spec).unwrap();
        let mut show = open(&spec).unwrap();
        for _ in 0..3 {
            match show.next().unwrap() {
                Next::Frame { frame, .. } => assert_eq!(frame.rgba[0], 200),
                Next::End | Next::Idle => panic!("a slideshow has an image every time"),
            }
        }
        // With none readable, both say so.
        std::fs::write(&b, b"not a png").unwrap();
        let e = show.next().err().unwrap().to_string();
        assert!(e.contains("not a readable image"), "{e}");
        let e = check(&spec).unwrap_err().to_string();
        assert!(e.contains("not a readable image"), "{e}");
        // A still image and a raw file are checked without playing them; a pattern always
        // plays.
        assert!(check(&SourceSpec::Image(b.clone())).is_err());
        let raw = |p: &Path| SourceSpec::Raw {
            path: Some(p.to_path_buf()),
            size: ImageSize::new(2, 1),
            format: RawFormat::Rgb24,
        };
        assert!(check(&raw(&b)).is_ok());
        assert!(check(&raw(&dir.path().join("missing"))).is_err());
        assert!(check(&raw(dir.path())).is_err());
    }
}
