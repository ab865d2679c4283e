//! Live playback in the core: where a content frame goes on its way to the projector, and the CPU
//! reference of the whole per-frame path that the GPU pass ([`crate::gpu`]) must reproduce.
//!
//! The chain (docs/architecture.md, "Playback" and "Spaces and conventions"), per content frame:
//! 1. **Desired camera view** `z'` (camera pixels): the content frame (any size, 8-bit
//!    sRGB-encoded values in \[0,1\]) is mapped into the display range (`low + (high − low)·v`),
//!    stretched into the *displayable area* (a camera-space rectangle of the canvas aspect inside
//!    the projector FOV) with bilinear resizing (half-pixel centres), its edge pixels repeated
//!    [`crate::fov::EDGE_MARGIN_PX`] camera pixels outward, black beyond
//!    ([`crate::fov::place_in_area`]); pixels outside the model's FOV mask are set to black, as
//!    the model's inputs were in training ([`crate::model::Model::infer`]).
//! 2. **Compensation image** (network pixels): the model's `π†(z')`: the baked grid samples `z'`
//!    (bilinear, align-corners, zero outside), then the photometric part.
//! 3. **Projector frame** (projector pixels): the compensation image stretched over the canvas
//!    with bilinear resizing, black elsewhere ([`place_on_canvas`]).
//!
//! Every step is the existing core function; [`reference_frame`] only chains them, so the CPU
//! reference of the GPU pass is exactly what the offline commands and the rig's closed loop do.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::fov::{self, DisplayRange};
use crate::model::Model;
use crate::raster::{CamImage, ImageSize, NetImage, PrjImage, Rect, Rgb, Space};
use crate::resize::resize_bilinear;

/// Where frames go: the placement parameters of the chain above.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Camera size (width, height), camera pixels; the model's.
    #[serde(with = "crate::raster::as_pair")]
    pub camera_size: ImageSize,
    /// The displayable area, camera pixels, where content frames are stretched.
    pub area: Rect,
    /// Range of camera values content is mapped into (see [`fov::display_range`]).
    pub range: DisplayRange,
    /// Network size (width, height), network pixels; the model's.
    #[serde(with = "crate::raster::as_pair")]
    pub network_size: ImageSize,
    /// Projector size (width, height), projector pixels; the display's native resolution.
    #[serde(with = "crate::raster::as_pair")]
    pub projector_size: ImageSize,
    /// Where the compensation image is stretched, projector pixels.
    pub canvas: Rect,
}

impl Placement {
    /// The placement for `model` on a display of `projector_size`: the model's canvas (default
    /// the full frame), the largest rectangle of the canvas aspect in the model's FOV mask, and
    /// `range` for the content values.
    pub fn for_model(
        model: &Model,
        projector_size: ImageSize,
        range: DisplayRange,
    ) -> Result<Self> {
        let ImageSize {
            width: pw,
            height: ph,
        } = projector_size;
        let canvas = model.meta.canvas.unwrap_or(Rect {
            x: 0,
            y: 0,
            width: pw,
            height: ph,
        });
        let area = fov::displayable_area(&model.fov, canvas.width as f64 / canvas.height as f64)?;
        let p = Self {
            camera_size: model.camera_size(),
            area,
            range,
            network_size: model.network_size(),
            projector_size,
            canvas,
        };
        p.validate()?;
        Ok(p)
    }

    /// Checks that the rectangles fit their frames and nothing is empty.
    pub fn validate(&self) -> Result<()> {
        let fits = |r: Rect,
                    ImageSize {
                        width: w,
                        height: h,
                    }: ImageSize| {
            r.width > 0 && r.height > 0 && r.x + r.width <= w && r.y + r.height <= h
        };
        if !fits(self.area, self.camera_size) {
            return Err(Error::Shape(format!(
                "displayable area {} does not fit the {} camera frame",
                self.area, self.camera_size
            )));
        }
        if !fits(self.canvas, self.projector_size) {
            return Err(Error::Shape(format!(
                "canvas {} does not fit the {} projector frame",
                self.canvas, self.projector_size
            )));
        }
        if self.network_size.width == 0 || self.network_size.height == 0 {
            return Err(Error::Shape("empty network size".into()));
        }
        Ok(())
    }
}

/// An 8-bit RGBA frame from a video source (content pixels, sRGB-encoded, alpha ignored).
#[derive(Clone, PartialEq, Eq)]
pub struct ContentFrame {
    pub width: usize,
    pub height: usize,
    /// Row-major RGBA, `width * height * 4` bytes.
    pub rgba: Vec<u8>,
}

impl std::fmt::Debug for ContentFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ContentFrame({}x{})", self.width, self.height)
    }
}

impl ContentFrame {
    pub fn from_rgba(width: usize, height: usize, rgba: Vec<u8>) -> Result<Self> {
        if rgba.len() != width * height * 4 || width == 0 || height == 0 {
            return Err(Error::Shape(format!(
                "RGBA frame {width}x{height} needs {} bytes, got {}",
                width * height * 4,
                rgba.len()
            )));
        }
        Ok(Self {
            width,
            height,
            rgba,
        })
    }

    /// From packed RGB bytes (`width * height * 3`).
    pub fn from_rgb(width: usize, height: usize, rgb: &[u8]) -> Result<Self> {
        if rgb.len() != width * height * 3 {
            return Err(Error::Shape(format!(
                "RGB frame {width}x{height} needs {} bytes, got {}",
                width * height * 3,
                rgb.len()
            )));
        }
        let mut rgba = Vec::with_capacity(width * height * 4);
        for px in rgb.chunks_exact(3) {
            rgba.extend_from_slice(&[px[0], px[1], px[2], 255]);
        }
        Self::from_rgba(width, height, rgba)
    }

    /// From an f32 image, rounded to 8 bits (as saving it would).
    pub fn from_image<S: Space>(img: &Rgb<S>) -> Self {
        let mut rgba = Vec::with_capacity(img.width() * img.height() * 4);
        for px in img.data().chunks_exact(3) {
            rgba.extend_from_slice(&[
                crate::pngio::to_u8(px[0]),
                crate::pngio::to_u8(px[1]),
                crate::pngio::to_u8(px[2]),
                255,
            ]);
        }
        Self {
            width: img.width(),
            height: img.height(),
            rgba,
        }
    }

    /// The frame as an f32 image (`v / 255`).
    pub fn to_image<S: Space>(&self) -> Rgb<S> {
        let data = self
            .rgba
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]].map(|v| v as f32 / 255.0))
            .collect();
        Rgb::from_vec(self.width, self.height, data).expect("checked size")
    }

    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
}

/// Step 1: the desired camera-view image of a content frame (before the FOV mask).
pub fn desired_view(content: &ContentFrame, p: &Placement) -> Result<CamImage> {
    let img: Rgb<crate::raster::Unspecified> = content.to_image();
    fov::place_in_area(&p.range.apply(&img), p.area, p.camera_size)
}

/// Steps 1–2: the compensation image (network pixels) of a content frame.
pub fn reference_network(model: &Model, content: &ContentFrame, p: &Placement) -> Result<NetImage> {
    model.infer(&desired_view(content, p)?)
}

/// Steps 1–3: the projector frame (projector pixels, f32, before 8-bit output) of a content
/// frame: the CPU reference of the GPU compensation pass.
pub fn reference_frame(model: &Model, content: &ContentFrame, p: &Placement) -> Result<PrjImage> {
    let net = reference_network(model, content, p)?;
    place_on_canvas(&net, p.canvas, p.projector_size)
}

/// Stretches `img` (e.g. a network-size projector image) over `canvas` of a black projector
/// frame of `size` (width, height), with bilinear resizing.
pub fn place_on_canvas<S: Space>(img: &Rgb<S>, canvas: Rect, size: ImageSize) -> Result<PrjImage> {
    let ImageSize {
        width: w,
        height: h,
    } = size;
    if canvas.width == 0
        || canvas.height == 0
        || canvas.x + canvas.width > w
        || canvas.y + canvas.height > h
    {
        return Err(Error::Shape(format!(
            "canvas {canvas} is empty or does not fit in the {w}x{h} projector frame"
        )));
    }
    if img.width() == 0 || img.height() == 0 {
        return Err(Error::Shape(
            "cannot place an empty image on the canvas".into(),
        ));
    }
    let fitted = resize_bilinear(img, canvas.width, canvas.height);
    if canvas
        == (Rect {
            x: 0,
            y: 0,
            width: w,
            height: h,
        })
    {
        return Ok(fitted.into_space());
    }
    let mut out = PrjImage::new(w, h);
    for y in 0..canvas.height {
        for x in 0..canvas.width {
            out.set(canvas.x + x, canvas.y + y, fitted.get(x, y));
        }
    }
    Ok(out)
}
