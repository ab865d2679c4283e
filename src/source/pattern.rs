//! Generated test patterns (`pattern:NAME`), paced at a frame rate.

use std::time::Duration;

use super::{Next, Pattern, VideoSource};
use crate::error::Result;
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// Colour bars, left to right.
const BARS: [[u8; 3]; 8] = [
    [255, 255, 255],
    [255, 255, 0],
    [0, 255, 255],
    [0, 255, 0],
    [255, 0, 255],
    [255, 0, 0],
    [0, 0, 255],
    [0, 0, 0],
];

pub struct Generator {
    pattern: Pattern,
    size: ImageSize,
    period: Duration,
    frames: Option<u64>,
    index: u64,
}

impl Generator {
    pub fn new(pattern: Pattern, size: ImageSize, fps: f64, frames: Option<u64>) -> Self {
        Self {
            pattern,
            size,
            period: Duration::from_secs_f64(1.0 / fps),
            frames,
            index: 0,
        }
    }
}

/// Frame `index` of `pattern` at `size` ((width, height), content pixels).
pub fn render(
    pattern: Pattern,
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    index: u64,
) -> Result<ContentFrame> {
    let mut rgba = Vec::with_capacity(w * h * 4);
    // The moving square: side h/4, one pixel per frame left to right, wrapping.
    let side = (h / 4).max(1);
    let sx = (index as usize) % w.max(1);
    let sy = (h - side) / 2;
    for y in 0..h {
        for x in 0..w {
            let px = match pattern {
                Pattern::Bars => BARS[x * 8 / w],
                Pattern::Ramp => {
                    let v = if w > 1 {
                        (x * 255 + (w - 1) / 2) / (w - 1)
                    } else {
                        0
                    } as u8;
                    [v; 3]
                }
                Pattern::Checker => {
                    let cell = (w.max(h) / 8).max(1);
                    [if (x / cell + y / cell) % 2 == 0 {
                        255
                    } else {
                        0
                    }; 3]
                }
                Pattern::Gray => [128; 3],
                Pattern::Moving => {
                    let inside = (x + w - sx) % w < side && y >= sy && y < sy + side;
                    if inside { [255; 3] } else { BARS[x * 8 / w] }
                }
            };
            rgba.extend_from_slice(&[px[0], px[1], px[2], 255]);
        }
    }
    ContentFrame::from_rgba(w, h, rgba)
}

impl VideoSource for Generator {
    fn describe(&self) -> String {
        format!(
            "pattern {:?} {} at {:.1} fps",
            self.pattern,
            self.size,
            1.0 / self.period.as_secs_f64()
        )
    }
    fn next(&mut self) -> Result<Next> {
        if self.frames.is_some_and(|n| self.index >= n) {
            return Ok(Next::End);
        }
        let frame = render(self.pattern, self.size, self.index)?;
        self.index += 1;
        Ok(Next::Frame {
            frame,
            wait: Some(self.period),
        })
    }
    fn ends_playback(&self) -> bool {
        self.frames.is_some()
    }
}
