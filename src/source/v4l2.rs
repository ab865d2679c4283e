//! `v4l2:/dev/videoN[?size=WxH]`: a V4L2 camera ([`crate::camera::V4l2Camera`]) played as a
//! video source, each frame as the device delivered it (8-bit RGBA, no pacing of its own).
//! Corrupt frames are skipped by the camera; a camera that goes away (unplugged, USB reset) is
//! reopened at the same path, and playback ends only when that fails.

use super::{Next, VideoSource};
use crate::camera::V4l2Camera;
use crate::error::Result;

impl VideoSource for V4l2Camera {
    fn describe(&self) -> String {
        V4l2Camera::describe(self)
    }

    fn next(&mut self) -> Result<Next> {
        if !self.is_connected() {
            self.reconnect()?;
        }
        let frame = match self.capture() {
            Ok(c) => c.rgba,
            Err(e) if !self.is_connected() => {
                tracing::warn!("{e}; reconnecting");
                self.reconnect()?;
                self.capture()?.rgba
            }
            Err(e) => return Err(e),
        };
        Ok(Next::Frame { frame, wait: None })
    }

    fn ends_playback(&self) -> bool {
        true
    }
}
