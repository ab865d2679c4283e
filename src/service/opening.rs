//! A `play` request's source, opened on a thread of its own before the picture that is on
//! stops: a film is prerolled, a stream connected, a camera opened, an image decoded. The
//! render loop (and, while idle, the engine with its watchdog) never waits for it; a source
//! that does not open within [`OPEN_TIMEOUT`] is refused, and the one playing goes on.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError, TryRecvError};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::source::{AudioOut, SourceSpec, VideoSource};

/// The longest a requested source may take to open: media's own check
/// ([`crate::source::MEDIA_CHECK_TIMEOUT`]) and a little more.
pub const OPEN_TIMEOUT: Duration =
    Duration::from_secs(crate::source::MEDIA_CHECK_TIMEOUT.as_secs() + 5);

/// An opened source, ready for the playback.
pub type Opened = Box<dyn VideoSource>;

/// The folders a client's request may name files in: `[playback] media` for a `play` request's
/// source, `[paths] models` for a `model` request. Paths are compared once links are resolved,
/// so a link leading out of a folder is refused; a path that does not exist is left to the
/// open, which says so.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Allowed {
    pub media: Vec<PathBuf>,
    pub models: Vec<PathBuf>,
}

impl Allowed {
    pub fn of(config: &crate::config::Config) -> Self {
        Self {
            media: config.playback.media.clone(),
            models: config.paths.models.clone(),
        }
    }

    /// Whether a requested source names only files in the media folders (a V4L2 device:
    /// under /dev).
    pub fn source(&self, spec: &SourceSpec) -> Result<()> {
        use crate::source::MediaSpec;
        let media = |p: &Path| inside(p, &self.media, "[playback] media");
        match spec {
            SourceSpec::Image(p) | SourceSpec::Folder { dir: p, .. } => media(p),
            SourceSpec::Raw { path: Some(p), .. } => media(p),
            SourceSpec::Media(MediaSpec::File(p)) => media(p),
            SourceSpec::Media(MediaSpec::Uri(u)) => match u.split_once("://") {
                Some((scheme, rest)) if scheme.eq_ignore_ascii_case("file") => {
                    // `file://HOST/PATH`: the path from its first slash, as GStreamer reads it
                    // (a percent-escaped one is refused: it could spell its way out).
                    let path = &rest[rest.find('/').unwrap_or(rest.len())..];
                    if path.contains('%') {
                        return Err(Error::Input(format!(
                            "uri:{u}: a file URI with escapes is not taken from a client; \
                             spell the path (file:PATH)"
                        )));
                    }
                    media(Path::new(path))
                }
                _ => Ok(()),
            },
            #[cfg(target_os = "linux")]
            SourceSpec::V4l2 { device, .. } => inside(device, &[PathBuf::from("/dev")], "/dev"),
            _ => Ok(()),
        }
    }

    /// Whether a requested model directory is in the model folders.
    pub fn model(&self, path: &Path) -> Result<()> {
        inside(path, &self.models, "[paths] models")
    }
}

/// Whether `path` (links resolved) is inside one of `folders` (links resolved); `key` names
/// the setting in the error.
fn inside(path: &Path, folders: &[PathBuf], key: &str) -> Result<()> {
    let Ok(real) = path.canonicalize() else {
        // Not there (or not reachable): nothing to read; the open says so.
        return Ok(());
    };
    if folders
        .iter()
        .filter_map(|f| f.canonicalize().ok())
        .any(|f| real.starts_with(&f))
    {
        return Ok(());
    }
    Err(Error::Input(format!(
        "{}: not in {key} ({}); a request may name only files there{}",
        super::clipped(&path.display().to_string()),
        folders
            .iter()
            .map(|f| f.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
        if real != path {
            format!(
                " (it leads to {})",
                super::clipped(&real.display().to_string())
            )
        } else {
            String::new()
        }
    )))
}

/// A source being opened.
pub struct Opening {
    /// The source as the request spelled it.
    pub text: String,
    started: Instant,
    result: mpsc::Receiver<Result<Opened>>,
}

impl Opening {
    /// Starts opening `text` (a source spelling a client asked for) with its sound to
    /// `audio`; its files must be in the media folders of `allowed`.
    pub fn start(text: String, audio: AudioOut, allowed: Allowed) -> Result<Self> {
        let (tx, result) = mpsc::channel();
        let spelled = text.clone();
        std::thread::Builder::new()
            .name("compend-open".into())
            .spawn(move || {
                let opened = SourceSpec::parse(&spelled).and_then(|spec| {
                    allowed.source(&spec)?;
                    crate::source::open_checked(&spec, &audio)
                });
                // No one waits any more (timed out, or the playback ended): the source is
                // dropped here, on this thread.
                let _ = tx.send(opened);
            })
            .map_err(|e| Error::Failed(format!("cannot start a thread to open the source: {e}")))?;
        Ok(Self {
            text,
            started: Instant::now(),
            result,
        })
    }

    /// The outcome once there is one, without waiting: the source, or why it is refused (it
    /// failed, or it took longer than [`OPEN_TIMEOUT`]).
    pub fn poll(&self) -> Option<Result<Opened>> {
        match self.result.try_recv() {
            Ok(r) => Some(r),
            Err(TryRecvError::Disconnected) => Some(Err(self.vanished())),
            Err(TryRecvError::Empty) if self.started.elapsed() >= OPEN_TIMEOUT => {
                Some(Err(self.too_slow()))
            }
            Err(TryRecvError::Empty) => None,
        }
    }

    /// Waits for the outcome, calling `alive` at least every second (the watchdog).
    pub fn wait(self, mut alive: impl FnMut()) -> Result<Opened> {
        loop {
            alive();
            match self.result.recv_timeout(Duration::from_secs(1)) {
                Ok(r) => return r,
                Err(RecvTimeoutError::Disconnected) => return Err(self.vanished()),
                Err(RecvTimeoutError::Timeout) if self.started.elapsed() >= OPEN_TIMEOUT => {
                    return Err(self.too_slow());
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
        }
    }

    fn too_slow(&self) -> Error {
        Error::Input(format!(
            "{}: did not open within {} s (a stream that does not answer, a device that does \
             not deliver, a file too large to read in time); the source playing goes on",
            super::clipped(&self.text),
            OPEN_TIMEOUT.as_secs()
        ))
    }

    fn vanished(&self) -> Error {
        Error::Failed(format!(
            "{}: opening it ended without an answer (see the log)",
            super::clipped(&self.text)
        ))
    }
}
