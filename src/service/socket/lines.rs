//! The framing: one request per line, capped at [`super::protocol::MAX_REQUEST_BYTES`]; a
//! subscription request; replies written within [`WRITE_TIMEOUT`].
//!
//! Why not `tokio_util::codec::LinesCodec` with a maximum length: a `FramedRead` ends its stream
//! at the decoder's first error (tokio-rs/tokio#4166), so a line too long would close the
//! connection, and the codec refuses bytes that are not UTF-8 before the JSON parser can name
//! them; [`read_line`] answers such a line as malformed and reads on.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt};

use crate::service::protocol::MAX_REQUEST_BYTES;

/// How long a reply may take to write: a client that does not read its replies is closed.
pub(super) const WRITE_TIMEOUT: Duration = Duration::from_secs(10);

pub(super) enum Line {
    Complete,
    TooLong,
    End,
}

/// Reads one line into `buf` (without its newline), at most [`MAX_REQUEST_BYTES`]; the rest of
/// a longer line is read and thrown away.
pub(super) async fn read_line<R: tokio::io::AsyncBufRead + Unpin>(
    r: &mut R,
    buf: &mut Vec<u8>,
) -> std::io::Result<Line> {
    buf.clear();
    let mut too_long = false;
    loop {
        let chunk = r.fill_buf().await?;
        if chunk.is_empty() {
            // A last request without its newline still counts.
            return Ok(match (buf.is_empty(), too_long) {
                (_, true) => Line::TooLong,
                (true, false) => Line::End,
                (false, false) => Line::Complete,
            });
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (chunk.len(), false),
        };
        if !too_long {
            if buf.len() + take > MAX_REQUEST_BYTES {
                too_long = true;
                buf.clear();
            } else {
                buf.extend_from_slice(&chunk[..take]);
            }
        }
        r.consume(if done { take + 1 } else { take });
        if done {
            return Ok(if too_long {
                Line::TooLong
            } else {
                Line::Complete
            });
        }
    }
}

/// Whether `line` is `{"cmd":"subscribe"}` (with a `request_id`, or not): Some(its id).
pub(super) fn subscription(line: &[u8]) -> Option<Option<serde_json::Value>> {
    // Most lines are other requests: parsed here only when they may be this one.
    if !line.windows(9).any(|w| w == b"subscribe") {
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(line).ok()?;
    let o = v.as_object()?;
    if o.get("cmd")?.as_str()? != "subscribe" || o.keys().any(|k| k != "cmd" && k != "request_id") {
        return None;
    }
    Some(o.get("request_id").cloned())
}

/// Writes `text` within [`WRITE_TIMEOUT`].
pub(super) async fn send_line<W: tokio::io::AsyncWrite + Unpin>(
    w: &mut W,
    text: String,
) -> std::io::Result<()> {
    match tokio::time::timeout(WRITE_TIMEOUT, w.write_all(text.as_bytes())).await {
        Ok(r) => r,
        Err(_) => Err(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            "the client did not read what it was sent",
        )),
    }
}
