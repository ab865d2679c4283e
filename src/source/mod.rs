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
                    RawInput::Stream(Box::new(std::io::stdin())),
                    "standard input".into(),
                ),
                Some(p) => (RawInput::Polled(open_raw(p)?), p.display().to_string()),
            };
            let len = size.width * size.height * format.bytes_per_pixel();
            Ok(Box::new(Raw {
                reader,
                name,
                size: *size,
                format: *format,
                frames: 0,
                buf: vec![0; len],
                got: 0,
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

/// The source `spec` names, opened and shown to play, without a frame lost to the playback:
/// what the service does with a `play` request, on a thread of its own, before the picture
/// that is on stops. A still image is decoded, a folder's first image that decodes is read
/// (and shown first), a raw source's file or FIFO and a camera's device are opened (a FIFO
/// without a writer yet opens at once; its frames come when one writes), media is brought to
/// its first frame within [`MEDIA_CHECK_TIMEOUT`]. An image file is looked at by its header
/// before it is read whole, so a folder of large files that are not images is refused fast.
pub fn open_checked(spec: &SourceSpec, audio: &AudioOut) -> Result<Box<dyn VideoSource>> {
    match spec {
        SourceSpec::Media(m) => {
            media::check(m, MEDIA_CHECK_TIMEOUT)?;
            open_with(spec, audio)
        }
        SourceSpec::Folder { dir, period } => {
            let mut show = Slideshow::new(dir, *period)?;
            let first = show.next()?;
            Ok(Box::new(Primed {
                first: Some(first),
                inner: Box::new(show),
            }))
        }
        _ => open_with(spec, audio),
    }
}

/// A source whose first answer was taken to show that it plays: given back first.
struct Primed {
    first: Option<Next>,
    inner: Box<dyn VideoSource>,
}

impl VideoSource for Primed {
    fn describe(&self) -> String {
        self.inner.describe()
    }
    fn prepare(&mut self) -> Result<()> {
        self.inner.prepare()
    }
    fn next(&mut self) -> Result<Next> {
        match self.first.take() {
            Some(first) => Ok(first),
            None => self.inner.next(),
        }
    }
    fn ends_playback(&self) -> bool {
        self.inner.ends_playback()
    }
    fn set_live(&mut self, live: bool) {
        self.inner.set_live(live);
    }
    fn control(&self) -> Option<crate::media::Control> {
        self.inner.control()
    }
}

/// Decodes a PNG or JPEG file to an RGBA frame. Its header is read first: a file that is not
/// an image, or one larger than [`ImageSize::MAX_PIXELS`], is refused before the rest is read.
pub fn read_image(path: &Path) -> Result<ContentFrame> {
    use std::io::Seek;
    const WHAT: &str = "an image (PNG or JPEG)";
    let (mut file, len) = crate::files::open_regular(path, WHAT)?;
    let unreadable = |e: &dyn std::fmt::Display| {
        Error::Input(format!("{}: not a readable image ({e})", path.display()))
    };
    let (w, h) = image::ImageReader::new(std::io::BufReader::new(&mut file))
        .with_guessed_format()
        .map_err(|e| Error::io(path, "read", e))?
        .into_dimensions()
        .map_err(|e| unreadable(&e))?;
    if (w as usize).saturating_mul(h as usize) > ImageSize::MAX_PIXELS {
        return Err(Error::Input(format!(
            "{}: {w}x{h} pixels; an image may have at most {} million",
            path.display(),
            ImageSize::MAX_PIXELS / 1_000_000
        )));
    }
    file.rewind().map_err(|e| Error::io(path, "read", e))?;
    let bytes = crate::files::read_opened(file, len, (path, WHAT), crate::files::MAX_IMAGE_BYTES)?;
    let img = image::load_from_memory(&bytes).map_err(|e| unreadable(&e))?;
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

/// Opens a raw source's file, FIFO or device for reading without waiting: a FIFO's open
/// would wait for its writer, and a thread waiting there could not be told to stop.
fn open_raw(p: &Path) -> Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(p)
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => Error::Missing {
                path: p.to_path_buf(),
                expected: "a raw source (a file, FIFO or device of raw frames)".into(),
            },
            _ => Error::io(p, "open raw source", e),
        })?;
    let meta = file.metadata().map_err(|e| Error::io(p, "inspect", e))?;
    if meta.is_dir() {
        return Err(Error::Input(format!(
            "{}: a folder, not a raw source (folder:PATH shows a folder's images)",
            p.display()
        )));
    }
    Ok(file)
}

/// How long a raw source waits for bytes before it lets its thread look up (to be stopped).
const RAW_POLL: Duration = Duration::from_millis(100);

/// Whether `file` has bytes to read (or its writer left) within `timeout`.
fn readable(file: &std::fs::File, timeout: Duration) -> std::io::Result<bool> {
    use nix::poll::{PollFd, PollFlags, PollTimeout};
    use std::os::fd::AsFd;
    let mut fds = [PollFd::new(file.as_fd(), PollFlags::POLLIN)];
    let timeout = PollTimeout::try_from(timeout).unwrap_or(PollTimeout::MAX);
    match nix::poll::poll(&mut fds, timeout) {
        Ok(0) | Err(nix::errno::Errno::EINTR) => Ok(false),
        Ok(_) => Ok(true),
        Err(e) => Err(std::io::Error::from(e)),
    }
}

/// Where a [`Raw`] source reads from.
enum RawInput {
    /// A file, FIFO or device opened without blocking: each read waits at most [`RAW_POLL`].
    /// (On Linux a FIFO that never had a writer since it was opened is neither readable nor
    /// hung up, so the wait goes on until one writes.)
    Polled(std::fs::File),
    /// Standard input, read as it blocks.
    Stream(Box<dyn Read + Send>),
}

/// Raw 8-bit frames back to back on a pipe, a FIFO or in a file.
struct Raw {
    reader: RawInput,
    name: String,
    size: ImageSize,
    format: RawFormat,
    frames: u64,
    /// The frame being read, and how many of its bytes came.
    buf: Vec<u8>,
    got: usize,
}

impl VideoSource for Raw {
    fn describe(&self) -> String {
        format!(
            "raw {:?} {} frames from {}",
            self.format, self.size, self.name
        )
    }

    fn next(&mut self) -> Result<Next> {
        let ImageSize {
            width: w,
            height: h,
        } = self.size;
        let len = self.buf.len();
        let io_error = |name: &str, e| Error::Io {
            path: PathBuf::from(name),
            op: "read raw frames",
            source: e,
        };
        while self.got < len {
            let read = match &mut self.reader {
                RawInput::Polled(file) => {
                    if !readable(file, RAW_POLL).map_err(|e| io_error(&self.name, e))? {
                        // Nothing yet: the feed's thread looks whether it was stopped.
                        return Ok(Next::Idle);
                    }
                    file.read(&mut self.buf[self.got..])
                }
                RawInput::Stream(r) => r.read(&mut self.buf[self.got..]),
            };
            match read {
                Ok(0) => break,
                Ok(n) => self.got += n,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::Interrupted | std::io::ErrorKind::WouldBlock
                    ) => {}
                Err(e) => return Err(io_error(&self.name, e)),
            }
        }
        let got = std::mem::take(&mut self.got);
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
            RawFormat::Rgb24 => ContentFrame::from_rgb(w, h, &self.buf)?,
            RawFormat::Rgba => ContentFrame::from_rgba(w, h, self.buf.clone())?,
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
    fn a_slideshow_skips_a_damaged_image_and_open_checked_shows_what_play_would() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.png"), dir.path().join("b.png"));
        std::fs::write(&a, &png(10)[..20]).unwrap();
        std::fs::write(&b, png(200)).unwrap();
        let spec = SourceSpec::Folder {
            dir: dir.path().to_path_buf(),
            period: Duration::from_secs(1),
        };
        // The first image is the damaged one: the check, as the show, goes on past it to the
        // good one, which it shows first (nothing read is lost), and again and again.
        let audio = AudioOut::default();
        let mut checked = open_checked(&spec, &audio).unwrap();
        let mut show = open(&spec).unwrap();
        for _ in 0..3 {
            for s in [&mut checked, &mut show] {
                match s.next().unwrap() {
                    Next::Frame { frame, .. } => assert_eq!(frame.rgba[0], 200),
                    Next::End | Next::Idle => panic!("a slideshow has an image every time"),
                }
            }
        }
        // With none readable, both say so.
        std::fs::write(&b, b"not a png").unwrap();
        let e = show.next().err().unwrap().to_string();
        assert!(e.contains("not a readable image"), "{e}");
        let e = open_checked(&spec, &audio).err().unwrap().to_string();
        assert!(e.contains("not a readable image"), "{e}");
        assert!(open_checked(&SourceSpec::Image(b.clone()), &audio).is_err());
        // A raw source's file is opened; a missing one or a folder is refused.
        let raw = |p: &Path| SourceSpec::Raw {
            path: Some(p.to_path_buf()),
            size: ImageSize::new(2, 1),
            format: RawFormat::Rgb24,
        };
        assert!(open_checked(&raw(&b), &audio).is_ok());
        assert!(open_checked(&raw(&dir.path().join("missing")), &audio).is_err());
        let e = open_checked(&raw(dir.path()), &audio)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("a folder"), "{e}");
    }

    /// A large file that is not an image is refused from its header, without being read
    /// whole; an image claiming more pixels than compend takes, from its header too.
    #[test]
    fn an_image_is_refused_by_its_header_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let big = dir.path().join("big.png");
        let f = std::fs::File::create(&big).unwrap();
        // Sparse: 900 MB that take no disk and would take seconds to read.
        f.set_len(900 << 20).unwrap();
        let t = std::time::Instant::now();
        let e = read_image(&big).unwrap_err().to_string();
        assert!(e.contains("not a readable image"), "{e}");
        assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
        // A PNG header of 100000x100000 pixels and nothing after it.
        let mut header = png(1);
        header[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        header[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        // The IHDR chunk's CRC-32 (type and data, bytes 12..29), bit by bit.
        let mut crc = !0u32;
        for &byte in &header[12..29] {
            crc ^= u32::from(byte);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        header[29..33].copy_from_slice(&(!crc).to_be_bytes());
        let huge = dir.path().join("huge.png");
        std::fs::write(&huge, &header).unwrap();
        let e = read_image(&huge).unwrap_err().to_string();
        assert!(e.contains("100000x100000"), "{e}");
    }

    /// A FIFO with no writer opens at once and its reads give way (the feed's thread can be
    /// stopped); a writer's frames then come through.
    #[test]
    fn a_fifo_without_a_writer_does_not_hold_its_thread() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
        let spec = SourceSpec::Raw {
            path: Some(fifo.clone()),
            size: ImageSize::new(2, 1),
            format: RawFormat::Rgb24,
        };
        let t = std::time::Instant::now();
        let mut src = open_checked(&spec, &AudioOut::default()).unwrap();
        assert!(matches!(src.next().unwrap(), Next::Idle));
        assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
        let mut w = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
        // Half a frame, then the rest: the frame comes whole.
        std::io::Write::write_all(&mut w, &[1, 2, 3]).unwrap();
        assert!(matches!(src.next().unwrap(), Next::Idle));
        std::io::Write::write_all(&mut w, &[4, 5, 6]).unwrap();
        match src.next().unwrap() {
            Next::Frame { frame, .. } => {
                assert_eq!(&frame.rgba[..8], &[1, 2, 3, 255, 4, 5, 6, 255])
            }
            _ => panic!("a frame was written"),
        }
        drop(w);
        assert!(matches!(src.next().unwrap(), Next::End));
    }
}
