//! Library error type. Every variant names the file, key, value or shape involved, and
//! [`Error::exit_code`] tells the CLI whether it was the user's input (2) or the operation (1).

use std::path::PathBuf;

use crate::size::ImageSize;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file that was expected is not there.
    #[error("{}: missing ({expected})", path.display())]
    Missing { path: PathBuf, expected: String },

    /// A file exists but could not be read or written.
    #[error("{}: {op} failed: {source}", path.display())]
    Io {
        path: PathBuf,
        op: &'static str,
        #[source]
        source: std::io::Error,
    },

    /// A file is not a decodable image of the expected kind.
    #[error("{}: not a readable PNG image ({reason})", path.display())]
    Decode { path: PathBuf, reason: String },

    /// An image has the wrong dimensions.
    #[error("{}: image is {got}, expected {expected}{}", path.display(), if why.is_empty() { String::new() } else { format!(" ({why})") })]
    Size {
        path: PathBuf,
        got: ImageSize,
        expected: ImageSize,
        why: String,
    },

    /// Bad user input that is not tied to one file (an argument, a folder layout, a value).
    #[error("{0}")]
    Input(String),

    /// In-memory data of incompatible shapes was combined (a programming or data error).
    #[error("shape mismatch: {0}")]
    Shape(String),

    /// The operation could not be carried out on valid input (e.g. nothing lit in the captures).
    #[error("{0}")]
    Failed(String),

    /// The operation was stopped on request (a service shutting down, a client's `stop`);
    /// what it wrote so far is consistent (captures are resumed, no model was installed).
    #[error("{0} was cancelled")]
    Cancelled(String),

    /// A tensor operation failed (candle): out of memory, a device error, or shapes that do not
    /// fit (a programming error). The cause is kept.
    #[error("tensor operation failed: {0}")]
    Candle(#[from] candle_core::Error),

    /// Media could not be played or written (GStreamer): `message` says which and why in words;
    /// `input` says whether the request was at fault (a missing file, not media, a codec no
    /// plugin decodes: exit 2) or the operation (a stream or device that failed: exit 1).
    /// GStreamer's own error is kept as the source.
    #[error("{message}")]
    Media {
        message: String,
        input: bool,
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
    },

    /// The GPU (wgpu) failed: no adapter, a lost device, a failed read-back. The cause is kept.
    #[error("GPU: {what}: {source}")]
    Gpu {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
}

impl Error {
    /// Process exit code for this error: 2 for usage or input errors, 1 for failed operations.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Missing { .. } | Error::Decode { .. } | Error::Size { .. } | Error::Input(_) => {
                2
            }
            Error::Media { input, .. } => {
                if *input {
                    2
                } else {
                    1
                }
            }
            // I/O failures (disk full, permission denied) are the operation's, not the user's
            // input: a service manager restarts on 1 and gives up on 2.
            Error::Io { .. }
            | Error::Shape(_)
            | Error::Failed(_)
            | Error::Cancelled(_)
            | Error::Candle(_)
            | Error::Gpu { .. } => 1,
        }
    }

    /// A GPU error with what was being done.
    pub fn gpu(
        what: impl Into<String>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        Error::Gpu {
            what: what.into(),
            source: Box::new(source),
        }
    }

    pub fn io(path: impl Into<PathBuf>, op: &'static str, source: std::io::Error) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            Error::Missing {
                path,
                expected: format!("no such file or folder; needed to {op}"),
            }
        } else {
            Error::Io { path, op, source }
        }
    }
}
