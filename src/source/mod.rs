//! Video sources for playback: still images, slideshows, raw frames on a pipe or FIFO, V4L2
//! cameras ([`crate::camera`]) and generated test patterns (spellings in [`spec::HELP`]), and the [`Feed`]
//! that runs a source on its own thread so decoding never blocks the render loop.
//!
//! Frames are 8-bit RGBA, sRGB-encoded as stored ([`ContentFrame`], content pixels).

pub mod feed;
pub mod pattern;
pub mod spec;
#[cfg(target_os = "linux")]
pub mod v4l2;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

pub use feed::{Feed, FeedMode, FeedStats, Poll};
pub use spec::{HELP, Pattern, RawFormat, SourceSpec};

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
    /// No more frames.
    End,
}

/// A video source. `next` may block (reading a pipe, waiting for a camera).
pub trait VideoSource: Send {
    /// For messages: what is being played.
    fn describe(&self) -> String;
    /// The next frame, or the end.
    fn next(&mut self) -> Result<Next>;
    /// Whether playback should end when the source ends (streams), rather than hold the last
    /// frame (still images).
    fn ends_playback(&self) -> bool;
}

/// Opens the source a spec names.
pub fn open(spec: &SourceSpec) -> Result<Box<dyn VideoSource>> {
    match spec {
        SourceSpec::Image(path) => Ok(Box::new(Still {
            path: path.clone(),
            frame: Some(read_image(path)?),
        })),
        SourceSpec::Folder { dir, period } => Ok(Box::new(Slideshow::new(dir, *period)?)),
        SourceSpec::Raw { path, size, format } => {
            let (reader, name): (Box<dyn Read + Send>, String) = match path {
                None => (Box::new(std::io::stdin()), "standard input".into()),
                Some(p) => (
                    Box::new(
                        std::fs::File::open(p).map_err(|e| Error::io(p, "open raw source", e))?,
                    ),
                    p.display().to_string(),
                ),
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

/// Decodes a PNG or JPEG file to an RGBA frame.
pub fn read_image(path: &Path) -> Result<ContentFrame> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, "read", e))?;
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
    fn next(&mut self) -> Result<Next> {
        let path = &self.files[self.index % self.files.len()];
        self.index += 1;
        Ok(Next::Frame {
            frame: read_image(path)?,
            wait: Some(self.period),
        })
    }
    fn ends_playback(&self) -> bool {
        false
    }
}

/// Raw 8-bit frames back to back on a pipe, a FIFO or in a file.
struct Raw {
    reader: Box<dyn Read + Send>,
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

    fn next(&mut self) -> Result<Next> {
        let ImageSize {
            width: w,
            height: h,
        } = self.size;
        let len = w * h * self.format.bytes_per_pixel();
        let mut buf = vec![0u8; len];
        let mut got = 0;
        while got < len {
            match self.reader.read(&mut buf[got..]) {
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
