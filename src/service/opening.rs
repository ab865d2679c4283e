//! A `play` request's source, opened on a thread of its own before the picture that is on
//! stops: a film is prerolled, a stream connected, a camera opened, an image decoded. The
//! render loop (and, while idle, the engine with its watchdog) never waits for it; a source
//! that does not open within [`OPEN_TIMEOUT`] is refused, and the one playing goes on.

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

/// A source being opened.
pub struct Opening {
    /// The source as the request spelled it.
    pub text: String,
    started: Instant,
    result: mpsc::Receiver<Result<Opened>>,
}

impl Opening {
    /// Starts opening `text` (a source spelling) with its sound to `audio`.
    pub fn start(text: String, audio: AudioOut) -> Result<Self> {
        let (tx, result) = mpsc::channel();
        let spelled = text.clone();
        std::thread::Builder::new()
            .name("compend-open".into())
            .spawn(move || {
                let opened = SourceSpec::parse(&spelled)
                    .and_then(|spec| crate::source::open_checked(&spec, &audio));
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
