//! Images in the core: RGB f32 images, single-channel planes, boolean masks and sampling grids,
//! each tagged at the type level with the pixel space it lives in (camera, projector, network).
//!
//! Pixel values are f32, nominally in [0,1], sRGB-encoded exactly as stored in 8-bit PNGs (no
//! colour management, no linearisation here). Storage is row-major, interleaved RGB: the value of
//! channel `c` at column `x`, row `y` is `data[(y * width + x) * 3 + c]`.

use std::fmt;
use std::marker::PhantomData;

use crate::error::{Error, Result};

mod levels;

pub use crate::size::{ImageSize, as_pair, as_pair_opt};
pub use levels::{Levels, ReadRgb};

/// A pixel space marker. Images of different spaces cannot be mixed by accident; conversions
/// between spaces are explicit (a warp, a placement on the canvas, or [`Rgb::into_space`]).
pub trait Space: Copy + Clone + Default + fmt::Debug + PartialEq + Send + Sync + 'static {
    const NAME: &'static str;
}

/// Camera pixels (captures x̃, surface image s̃, desired viewer images z').
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Camera;
/// Projector pixels (what the projector window shows; structured-light patterns).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Projector;
/// Network pixels (the resolution the models work at, default 256×256).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Network;
/// Pixels whose space is not known or does not matter (e.g. files compared by `compend metrics`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Unspecified;

impl Space for Camera {
    const NAME: &'static str = "camera";
}
impl Space for Projector {
    const NAME: &'static str = "projector";
}
impl Space for Network {
    const NAME: &'static str = "network";
}
impl Space for Unspecified {
    const NAME: &'static str = "unspecified";
}

/// An RGB image with f32 channels in space `S`.
#[derive(Clone, PartialEq)]
pub struct Rgb<S> {
    width: usize,
    height: usize,
    data: Vec<f32>,
    _space: PhantomData<S>,
}

pub type CamImage = Rgb<Camera>;
pub type PrjImage = Rgb<Projector>;
pub type NetImage = Rgb<Network>;

impl<S: Space> fmt::Debug for Rgb<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Rgb<{}>({}x{})", S::NAME, self.width, self.height)
    }
}

impl<S: Space> Rgb<S> {
    /// A black image.
    pub fn new(width: usize, height: usize) -> Self {
        Self::filled(width, height, [0.0; 3])
    }

    /// An image filled with one colour.
    pub fn filled(width: usize, height: usize, rgb: [f32; 3]) -> Self {
        let mut data = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            data.extend_from_slice(&rgb);
        }
        Self::wrap(width, height, data)
    }

    /// Wraps interleaved RGB data; the length must be `width * height * 3`.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height * 3 {
            return Err(Error::Shape(format!(
                "{} RGB image {}x{} needs {} values, got {}",
                S::NAME,
                width,
                height,
                width * height * 3,
                data.len()
            )));
        }
        Ok(Self::wrap(width, height, data))
    }

    /// Builds an image from a function of pixel coordinates (x, y).
    pub fn from_fn(
        width: usize,
        height: usize,
        mut f: impl FnMut(usize, usize) -> [f32; 3],
    ) -> Self {
        let mut data = Vec::with_capacity(width * height * 3);
        for y in 0..height {
            for x in 0..width {
                data.extend_from_slice(&f(x, y));
            }
        }
        Self::wrap(width, height, data)
    }

    fn wrap(width: usize, height: usize, data: Vec<f32>) -> Self {
        Self {
            width,
            height,
            data,
            _space: PhantomData,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    /// Width × height in pixels.
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }
    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }

    /// The pixel at column `x`, row `y`. Panics when out of bounds (a programming error).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    #[inline]
    pub fn set(&mut self, x: usize, y: usize, rgb: [f32; 3]) {
        let i = (y * self.width + x) * 3;
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// Re-tags the image with another space without touching pixels. Use only where the pixels
    /// really are in the other space (e.g. a network-sized projector image placed 1:1).
    pub fn into_space<T: Space>(self) -> Rgb<T> {
        Rgb::<T>::wrap(self.width, self.height, self.data)
    }

    /// Applies `f` to every channel value.
    pub fn map(&self, mut f: impl FnMut(f32) -> f32) -> Self {
        Self::wrap(
            self.width,
            self.height,
            self.data.iter().map(|&v| f(v)).collect(),
        )
    }

    /// Clamps every value to [0, 1].
    pub fn clamp01(&self) -> Self {
        self.map(|v| v.clamp(0.0, 1.0))
    }

    /// One channel (0 = R, 1 = G, 2 = B) as a plane.
    pub fn channel(&self, c: usize) -> Plane<S> {
        Plane::from_fn(self.width, self.height, |x, y| {
            self.data[(y * self.width + x) * 3 + c]
        })
    }

    /// Luma with Rec. 601 weights on the encoded values (as OpenCV's RGB2GRAY).
    pub fn to_gray(&self) -> Plane<S> {
        let data = self
            .data
            .chunks_exact(3)
            .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
            .collect();
        Plane::wrap(self.width, self.height, data)
    }

    /// Builds an RGB image from three planes of equal size.
    pub fn from_channels(r: &Plane<S>, g: &Plane<S>, b: &Plane<S>) -> Result<Self> {
        if r.size() != g.size() || r.size() != b.size() {
            return Err(Error::Shape(format!(
                "channel planes differ in size: ({}, {}), ({}, {}), ({}, {})",
                r.width, r.height, g.width, g.height, b.width, b.height
            )));
        }
        let mut data = Vec::with_capacity(r.data.len() * 3);
        for i in 0..r.data.len() {
            data.extend_from_slice(&[r.data[i], g.data[i], b.data[i]]);
        }
        Ok(Self::wrap(r.width, r.height, data))
    }

    /// Sets every pixel outside `mask` to black.
    pub fn masked(&self, mask: &Mask<S>) -> Result<Self> {
        self.clone().into_masked(mask)
    }

    /// [`Self::masked`], in place: no second copy of the image.
    pub fn into_masked(mut self, mask: &Mask<S>) -> Result<Self> {
        check_same_size(self.size(), mask.size(), "masking")?;
        for (px, &m) in self.data.chunks_exact_mut(3).zip(&mask.data) {
            if !m {
                px.fill(0.0);
            }
        }
        Ok(self)
    }

    /// Copies the rectangle `r` out of the image.
    pub fn crop(&self, r: Rect) -> Result<Self> {
        if r.x + r.width > self.width || r.y + r.height > self.height {
            return Err(Error::Shape(format!(
                "crop {r} does not fit in {}x{} {} image",
                self.width,
                self.height,
                S::NAME
            )));
        }
        Ok(Self::from_fn(r.width, r.height, |x, y| {
            self.get(r.x + x, r.y + y)
        }))
    }
}

/// A single-channel f32 image in space `S` (luma, a channel, a difference image, a weight map).
#[derive(Clone, PartialEq)]
pub struct Plane<S> {
    width: usize,
    height: usize,
    data: Vec<f32>,
    _space: PhantomData<S>,
}

impl<S: Space> fmt::Debug for Plane<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Plane<{}>({}x{})", S::NAME, self.width, self.height)
    }
}

impl<S: Space> Plane<S> {
    pub fn new(width: usize, height: usize) -> Self {
        Self::wrap(width, height, vec![0.0; width * height])
    }

    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height {
            return Err(Error::Shape(format!(
                "{} plane {}x{} needs {} values, got {}",
                S::NAME,
                width,
                height,
                width * height,
                data.len()
            )));
        }
        Ok(Self::wrap(width, height, data))
    }

    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self::wrap(width, height, data)
    }

    fn wrap(width: usize, height: usize, data: Vec<f32>) -> Self {
        Self {
            width,
            height,
            data,
            _space: PhantomData,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
    pub fn data(&self) -> &[f32] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: f32) {
        self.data[y * self.width + x] = v;
    }
    pub fn map(&self, mut f: impl FnMut(f32) -> f32) -> Self {
        Self::wrap(
            self.width,
            self.height,
            self.data.iter().map(|&v| f(v)).collect(),
        )
    }
    pub fn into_space<T: Space>(self) -> Plane<T> {
        Plane::<T>::wrap(self.width, self.height, self.data)
    }
    /// The same value in all three channels.
    pub fn to_rgb(&self) -> Rgb<S> {
        let data = self.data.iter().flat_map(|&v| [v, v, v]).collect();
        Rgb::wrap(self.width, self.height, data)
    }
    /// Pixels whose value is strictly above `t`.
    pub fn threshold(&self, t: f32) -> Mask<S> {
        Mask::wrap(
            self.width,
            self.height,
            self.data.iter().map(|&v| v > t).collect(),
        )
    }
}

/// A boolean mask in space `S` (true = inside).
#[derive(Clone, PartialEq, Eq)]
pub struct Mask<S> {
    width: usize,
    height: usize,
    data: Vec<bool>,
    _space: PhantomData<S>,
}

impl<S: Space> fmt::Debug for Mask<S> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "Mask<{}>({}x{}, {} set)",
            S::NAME,
            self.width,
            self.height,
            self.count()
        )
    }
}

impl<S: Space> Mask<S> {
    pub fn new(width: usize, height: usize) -> Self {
        Self::wrap(width, height, vec![false; width * height])
    }
    pub fn full(width: usize, height: usize) -> Self {
        Self::wrap(width, height, vec![true; width * height])
    }
    pub fn from_vec(width: usize, height: usize, data: Vec<bool>) -> Result<Self> {
        if data.len() != width * height {
            return Err(Error::Shape(format!(
                "{} mask {}x{} needs {} values, got {}",
                S::NAME,
                width,
                height,
                width * height,
                data.len()
            )));
        }
        Ok(Self::wrap(width, height, data))
    }
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> bool) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self::wrap(width, height, data)
    }
    fn wrap(width: usize, height: usize, data: Vec<bool>) -> Self {
        Self {
            width,
            height,
            data,
            _space: PhantomData,
        }
    }
    pub fn width(&self) -> usize {
        self.width
    }
    pub fn height(&self) -> usize {
        self.height
    }
    pub fn size(&self) -> ImageSize {
        ImageSize::new(self.width, self.height)
    }
    pub fn data(&self) -> &[bool] {
        &self.data
    }
    pub fn data_mut(&mut self) -> &mut [bool] {
        &mut self.data
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> bool {
        self.data[y * self.width + x]
    }
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: bool) {
        self.data[y * self.width + x] = v;
    }
    /// Number of pixels set.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }
    /// The smallest rectangle holding every set pixel, or `None` for an empty mask.
    pub fn bounding_box(&self) -> Option<Rect> {
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for y in 0..self.height {
            for x in 0..self.width {
                if self.get(x, y) {
                    x0 = x0.min(x);
                    y0 = y0.min(y);
                    x1 = x1.max(x);
                    y1 = y1.max(y);
                }
            }
        }
        (x0 != usize::MAX).then(|| Rect {
            x: x0,
            y: y0,
            width: x1 - x0 + 1,
            height: y1 - y0 + 1,
        })
    }
    /// 1.0 where set, 0.0 elsewhere.
    pub fn to_plane(&self) -> Plane<S> {
        Plane::wrap(
            self.width,
            self.height,
            self.data
                .iter()
                .map(|&b| if b { 1.0 } else { 0.0 })
                .collect(),
        )
    }
    pub fn into_space<T: Space>(self) -> Mask<T> {
        Mask::<T>::wrap(self.width, self.height, self.data)
    }
}

/// An axis-aligned rectangle of whole pixels: columns `x..x+width`, rows `y..y+height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl fmt::Display for Rect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}+{}+{}", self.width, self.height, self.x, self.y)
    }
}

impl Rect {
    /// The whole of a frame of `size`, from its top-left pixel.
    pub fn covering(size: ImageSize) -> Self {
        Rect {
            x: 0,
            y: 0,
            width: size.width,
            height: size.height,
        }
    }

    pub fn area(&self) -> usize {
        self.width * self.height
    }
    pub fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.x && y >= self.y && x < self.x + self.width && y < self.y + self.height
    }
}

/// Errors unless two sizes are equal; `what` names the operation.
pub fn check_same_size(a: ImageSize, b: ImageSize, what: &str) -> Result<()> {
    if a != b {
        return Err(Error::Shape(format!("{what}: sizes differ, {a} vs {b}")));
    }
    Ok(())
}
