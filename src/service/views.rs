//! What the console shows of the camera: its latest frame (taken at most [`CAMERA_FPS`] times a
//! second from whichever thread grabs them, so the render loop never waits on the console),
//! the served model's projector field of view to draw over it ([`fov_overlay`]), and the last
//! monitoring check's pair, the view the projection should give beside the one the camera saw,
//! in camera pixels with their displayable area.
//!
//! Frames are kept as 8-bit sRGB-encoded RGB (the camera's encoded values, quantised); JPEG
//! encoding happens on the reader's side, once per frame however many pages ask.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::device::{ExposureRange, Frame, FrameSource};
use crate::pngio::to_u8;
use crate::raster::{CamImage, Camera, ImageSize, Mask, Rect};

/// Camera frames kept per second at most.
pub const CAMERA_FPS: f64 = 5.0;

/// An 8-bit RGB image, rows top to bottom (camera pixels).
#[derive(Clone, Debug, PartialEq)]
pub struct Rgb8 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl Rgb8 {
    pub fn of(img: &CamImage) -> Self {
        Self {
            width: img.width(),
            height: img.height(),
            data: img.data().iter().map(|&v| to_u8(v)).collect(),
        }
    }

    /// As a JPEG at `quality` (1 to 100).
    pub fn jpeg(&self, quality: u8) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality)
            .encode(
                &self.data,
                self.width as u32,
                self.height as u32,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| format!("JPEG of {}x{}: {e}", self.width, self.height))?;
        Ok(out)
    }
}

/// A kept frame: numbered so that a reader can tell a new one, with when it was taken.
#[derive(Clone, Debug)]
pub struct Kept {
    pub seq: u64,
    pub at: Instant,
    pub image: Arc<Rgb8>,
}

/// The last monitoring check's images.
#[derive(Clone, Debug)]
pub struct Pair {
    pub seq: u64,
    /// The view the projection should give.
    pub desired: Arc<Rgb8>,
    /// What the camera saw.
    pub seen: Arc<Rgb8>,
    /// The displayable area, camera pixels.
    pub area: Rect,
}

#[derive(Default)]
pub struct Views {
    camera: Mutex<Option<Kept>>,
    pair: Mutex<Option<Pair>>,
    /// The served model's projector field of view, camera pixels.
    fov: Mutex<Option<Arc<Mask<Camera>>>>,
}

impl Views {
    /// Offers a camera frame; kept when the last was kept more than 1/[`CAMERA_FPS`] s ago.
    pub fn offer_camera(&self, img: &CamImage) {
        let mut cam = self.camera.lock().unwrap_or_else(|e| e.into_inner());
        let due = cam
            .as_ref()
            .is_none_or(|k| k.at.elapsed() >= Duration::from_secs_f64(1.0 / CAMERA_FPS));
        if due {
            let seq = cam.as_ref().map_or(1, |k| k.seq + 1);
            *cam = Some(Kept {
                seq,
                at: Instant::now(),
                image: Arc::new(Rgb8::of(img)),
            });
        }
    }

    /// Keeps a camera frame whatever the rate (the setup view streams every frame).
    pub fn offer_camera_now(&self, img: &CamImage) {
        let mut cam = self.camera.lock().unwrap_or_else(|e| e.into_inner());
        let seq = cam.as_ref().map_or(1, |k| k.seq + 1);
        *cam = Some(Kept {
            seq,
            at: Instant::now(),
            image: Arc::new(Rgb8::of(img)),
        });
    }

    /// The latest camera frame kept.
    pub fn camera(&self) -> Option<Kept> {
        self.camera
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Keeps a monitoring check's images.
    pub fn set_pair(&self, desired: &CamImage, seen: &CamImage, area: Rect) {
        let mut p = self.pair.lock().unwrap_or_else(|e| e.into_inner());
        let seq = p.as_ref().map_or(1, |k| k.seq + 1);
        *p = Some(Pair {
            seq,
            desired: Arc::new(Rgb8::of(desired)),
            seen: Arc::new(Rgb8::of(seen)),
            area,
        });
    }

    /// The last monitoring check's images.
    pub fn pair(&self) -> Option<Pair> {
        self.pair.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The field of view of the model served from now on.
    pub fn set_fov(&self, fov: &Mask<Camera>) {
        *self.fov.lock().unwrap_or_else(|e| e.into_inner()) = Some(Arc::new(fov.clone()));
    }

    /// The served model's field of view, camera pixels.
    pub fn fov(&self) -> Option<Arc<Mask<Camera>>> {
        self.fov.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Dims what lies outside the field of view, in 8-bit RGBA (alpha 0 to 255).
const OUTSIDE: [u8; 4] = [0, 0, 0, 120];
/// The field of view's edge: the projector's light ends here.
const EDGE: [u8; 4] = [0, 229, 255, 255];

/// The picture laid over the camera view for the field of view `fov` (camera pixels), 8-bit
/// RGBA, rows top to bottom: transparent inside it, [`OUTSIDE`] beyond it, and [`EDGE`] on its
/// boundary (inside pixels with a 4-neighbour outside it, or on the image's border).
pub fn fov_overlay(fov: &Mask<Camera>) -> Vec<u8> {
    let (w, h) = (fov.width(), fov.height());
    let at = |x: usize, y: usize| fov.data()[y * w + x];
    let mut out = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        for x in 0..w {
            let px = if !at(x, y) {
                OUTSIDE
            } else {
                let edge = x == 0
                    || y == 0
                    || x + 1 == w
                    || y + 1 == h
                    || !at(x - 1, y)
                    || !at(x + 1, y)
                    || !at(x, y - 1)
                    || !at(x, y + 1);
                if edge { EDGE } else { [0, 0, 0, 0] }
            };
            out.extend_from_slice(&px);
        }
    }
    out
}

/// A camera whose frames the console sees as well (at its capped rate): everything else is the
/// camera's own.
pub struct Tapped<'a, C: FrameSource + ?Sized> {
    camera: &'a mut C,
    views: &'a Views,
}

impl<'a, C: FrameSource + ?Sized> Tapped<'a, C> {
    pub fn new(camera: &'a mut C, views: &'a Views) -> Self {
        Self { camera, views }
    }
}

impl<C: FrameSource + ?Sized> FrameSource for Tapped<'_, C> {
    fn size(&self) -> ImageSize {
        self.camera.size()
    }

    fn grab(&mut self) -> crate::error::Result<Frame> {
        let f = self.camera.grab()?;
        self.views.offer_camera(&f.image);
        Ok(f)
    }

    fn exposure(&self) -> Option<ExposureRange> {
        self.camera.exposure()
    }

    fn set_exposure(&mut self, value: f64) -> crate::error::Result<f64> {
        self.camera.set_exposure(value)
    }

    fn reconnect(&mut self) -> crate::error::Result<bool> {
        self.camera.reconnect()
    }
}

/// The difference of `a` and `b` as a heat map: per pixel the largest channel difference, from
/// black (none) through red and yellow to white (a quarter of full scale or more); outside
/// `area` dimmed to a quarter. Same sizes required.
pub fn heat_map(a: &Rgb8, b: &Rgb8, area: Rect) -> Result<Rgb8, String> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(format!(
            "heat map of {}x{} against {}x{}",
            a.width, a.height, b.width, b.height
        ));
    }
    let mut data = Vec::with_capacity(a.data.len());
    for (i, (pa, pb)) in a
        .data
        .chunks_exact(3)
        .zip(b.data.chunks_exact(3))
        .enumerate()
    {
        let d = pa
            .iter()
            .zip(pb)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        // 0..64 of 255 spread over three ramps.
        let t = (f32::from(d) / 64.0).min(1.0) * 3.0;
        let ramp = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        let mut px = [ramp(t), ramp(t - 1.0), ramp(t - 2.0)];
        let (x, y) = (i % a.width, i / a.width);
        if !area.contains(x, y) {
            px = px.map(|v| v / 4);
        }
        data.extend_from_slice(&px);
    }
    Ok(Rgb8 {
        width: a.width,
        height: a.height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: usize, h: usize, v: u8) -> Rgb8 {
        Rgb8 {
            width: w,
            height: h,
            data: vec![v; w * h * 3],
        }
    }

    #[test]
    fn the_heat_map_is_black_where_equal_and_white_past_a_quarter() {
        let area = Rect {
            x: 0,
            y: 0,
            width: 2,
            height: 1,
        };
        let a = flat(3, 1, 100);
        let mut b = flat(3, 1, 100);
        b.data[3] = 200; // pixel 1: 100 apart
        b.data[6] = 200; // pixel 2: 100 apart, outside the area
        let h = heat_map(&a, &b, area).unwrap();
        assert_eq!(&h.data[0..3], &[0, 0, 0]);
        assert_eq!(&h.data[3..6], &[255, 255, 255]);
        assert_eq!(&h.data[6..9], &[63, 63, 63]);
        assert!(heat_map(&a, &flat(2, 1, 0), area).is_err());
    }

    #[test]
    fn the_field_of_view_is_clear_inside_dimmed_outside_and_edged() {
        // A 4×3 camera with the projector's light on the 3×3 block at the right.
        let m = Mask::<Camera>::from_vec(
            4,
            3,
            vec![
                false, true, true, true, //
                false, true, true, true, //
                false, true, true, true,
            ],
        )
        .unwrap();
        let o = fov_overlay(&m);
        assert_eq!(o.len(), 4 * 3 * 4);
        let px = |x: usize, y: usize| &o[(y * 4 + x) * 4..(y * 4 + x) * 4 + 4];
        assert_eq!(px(0, 1), OUTSIDE);
        // Next to the dark column, and on the image's border: edge.
        assert_eq!(px(1, 1), EDGE);
        assert_eq!(px(3, 1), EDGE);
        assert_eq!(px(2, 0), EDGE);
        // The one pixel with all four neighbours lit: clear.
        assert_eq!(px(2, 1), [0, 0, 0, 0]);
    }

    #[test]
    fn a_camera_frame_is_kept_at_most_at_the_capped_rate() {
        let v = Views::default();
        let img = CamImage::filled(4, 3, [0.5, 0.5, 0.5]);
        v.offer_camera(&img);
        v.offer_camera(&img);
        assert_eq!(v.camera().unwrap().seq, 1);
        let jpeg = v.camera().unwrap().image.jpeg(80).unwrap();
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8]);
    }
}
