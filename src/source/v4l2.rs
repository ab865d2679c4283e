//! `v4l2:/dev/videoN[?size=WxH]`: a V4L2 camera ([`crate::camera::V4l2Camera`]) played as a
//! video source, each frame as the device delivered it (8-bit RGBA, no pacing of its own).

use super::{Next, VideoSource};
use crate::camera::V4l2Camera;
use crate::error::Result;

impl VideoSource for V4l2Camera {
    fn describe(&self) -> String {
        V4l2Camera::describe(self)
    }

    fn next(&mut self) -> Result<Next> {
        Ok(Next::Frame {
            frame: self.capture()?.rgba,
            wait: None,
        })
    }

    fn ends_playback(&self) -> bool {
        true
    }
}
