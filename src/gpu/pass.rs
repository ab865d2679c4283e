//! The compensation pass: content frame → projector frame, all on the GPU, built once per model
//! and display and reused per frame (only the content upload and the dispatches per frame: three
//! for `linear`, 17 for the CompenNet backbone).
//!
//! Stages (see [`crate::playback`] for the chain and its CPU reference):
//! 1. `shaders/place.wgsl`: content (rgba8unorm, content pixels) → desired camera view
//!    (rgba32float, camera pixels), FOV mask applied;
//! 2. the model's photometric stage ([`Photometric`]): desired view → compensation image
//!    (rgba32float, network pixels);
//! 3. `shaders/canvas.wgsl`: compensation image → projector frame (rgba8unorm, projector pixels,
//!    native resolution), ready to present or read back.

use bytemuck::{Pod, Zeroable};

use super::GpuContext;
use super::compennet::CompenNetStage;
use super::kernel::{Slot, Stage, image_texture, storage, uniform, view};
use super::linear::LinearStage;
use super::residual::ResidualStage;
use crate::error::{Error, Result};
use crate::fov::DisplayRange;
use crate::model::{Kind, Model};
use crate::playback::{ContentFrame, Placement};
use crate::raster::{ImageSize, NetImage, PrjImage, Rgb, Space};

const PLACE: &str = include_str!("../../shaders/place.wgsl");
const CANVAS: &str = include_str!("../../shaders/canvas.wgsl");

/// Format of the projector frame: 8-bit, values as the projector takes them (no sRGB re-encoding
/// by the GPU: the model's outputs already are projector input values).
pub const FRAME_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// The model's photometric part on the GPU: one variant per model family.
pub enum Photometric {
    /// `linear`, `linear-sl`: grid sample + per-pixel affine colour.
    Linear(LinearStage),
    /// The CompenNet++ family (`compennet++*`, `compennet-sl`): grid sample + the simplified
    /// CompenNet backbone (surface branch folded into constant bias maps).
    CompenNet(Box<CompenNetStage>),
    /// A residual rung: the `linear` stage, the CompenNet correction, and their sum.
    Residual(Box<ResidualStage>),
}

impl Photometric {
    /// The stage for `model`, or an input error naming what is not available on the GPU yet.
    pub fn for_model(ctx: &GpuContext, model: &Model) -> Result<Self> {
        match &model.kind {
            Kind::Linear { simplified, .. } => Ok(Self::Linear(LinearStage::new(
                ctx,
                simplified,
                model.camera_size(),
            )?)),
            Kind::CompenNet { simplified, .. } => Ok(Self::CompenNet(Box::new(
                CompenNetStage::new(ctx, simplified, model.camera_size())?,
            ))),
            Kind::Residual {
                base, correction, ..
            } => Ok(Self::Residual(Box::new(ResidualStage::new(
                ctx,
                base,
                correction,
                model.camera_size(),
            )?))),
        }
    }

    fn bind(
        &self,
        ctx: &GpuContext,
        desired: &wgpu::TextureView,
        network: &wgpu::TextureView,
    ) -> Vec<wgpu::BindGroup> {
        match self {
            Self::Linear(s) => vec![s.bind(ctx, desired, network)],
            Self::CompenNet(s) => s.bind(ctx, desired, network),
            Self::Residual(s) => s.bind(ctx, desired, network),
        }
    }

    fn dispatch(&self, pass: &mut wgpu::ComputePass<'_>, groups: &[wgpu::BindGroup]) {
        match self {
            Self::Linear(s) => {
                if let Some(g) = groups.first() {
                    s.dispatch(pass, g)
                }
            }
            Self::CompenNet(s) => s.dispatch(pass, groups),
            Self::Residual(s) => s.dispatch(pass, groups),
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PlaceParams {
    camera: [u32; 2],
    content: [u32; 2],
    area_origin: [u32; 2],
    area_size: [u32; 2],
    range: [f32; 2],
    /// Camera pixels the area's edge pixels are repeated outward ([`crate::fov::EDGE_MARGIN_PX`]).
    margin: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CanvasParams {
    projector: [u32; 2],
    network: [u32; 2],
    origin: [u32; 2],
    size: [u32; 2],
}

fn u2(size: ImageSize) -> [u32; 2] {
    [size.width as u32, size.height as u32]
}

/// The content texture and the bind group of stage 1, rebuilt when the content size changes.
struct Content {
    size: ImageSize,
    texture: wgpu::Texture,
    group: wgpu::BindGroup,
}

/// The images between the stages, each (width, height) in its space's pixels.
struct Images {
    /// The desired camera view: rgba32float, camera pixels.
    desired: wgpu::Texture,
    /// The compensation image: rgba32float, network pixels.
    network: wgpu::Texture,
    /// The projector frame: [`FRAME_FORMAT`], projector pixels.
    output: wgpu::Texture,
}

impl Images {
    fn new(ctx: &GpuContext, p: &Placement) -> Self {
        let st = wgpu::TextureUsages::STORAGE_BINDING;
        let f32x4 = wgpu::TextureFormat::Rgba32Float;
        Self {
            desired: image_texture(ctx, "desired view", p.camera_size, f32x4, st),
            network: image_texture(ctx, "compensation image", p.network_size, f32x4, st),
            output: image_texture(ctx, "projector frame", p.projector_size, FRAME_FORMAT, st),
        }
    }
}

/// The compensation pass for one model and one display.
/// The three stages of a [`CompensationPass`], in the order a frame runs them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PassStage {
    /// Content into the desired camera view (camera pixels).
    Place,
    /// The model: desired view to the compensation image (network or lattice pixels).
    Photometric,
    /// The compensation image stretched over the canvas (projector pixels).
    Canvas,
}

impl PassStage {
    pub const ALL: [Self; 3] = [Self::Place, Self::Photometric, Self::Canvas];

    pub fn name(self) -> &'static str {
        match self {
            Self::Place => "place",
            Self::Photometric => "photometric",
            Self::Canvas => "canvas",
        }
    }
}

pub struct CompensationPass {
    placement: Placement,
    place: Stage,
    place_params: wgpu::Buffer,
    fov: wgpu::Buffer,
    photometric: Photometric,
    canvas: Stage,
    desired: wgpu::Texture,
    network: wgpu::Texture,
    output: wgpu::Texture,
    /// The photometric stage's bind groups (built once with the desired view and network image).
    photometric_groups: Vec<wgpu::BindGroup>,
    canvas_group: wgpu::BindGroup,
    content: Option<Content>,
}

impl CompensationPass {
    /// The pass for `model` on a display of `display` projector pixels: content goes into the
    /// largest rectangle of the canvas aspect in the model's FOV mask with its values mapped into
    /// `range`, and the model's output is stretched over its canvas (default the whole display),
    /// as [`Placement::for_model`] places them.
    pub fn for_display(
        ctx: &GpuContext,
        model: &Model,
        display: ImageSize,
        range: DisplayRange,
    ) -> Result<Self> {
        let placement = Placement::for_model(model, display, range)?;
        Self::new(ctx, model, placement)
    }

    /// Compiles the stages and uploads the model's constants once.
    pub fn new(ctx: &GpuContext, model: &Model, placement: Placement) -> Result<Self> {
        placement.validate()?;
        if placement.camera_size != model.camera_size()
            || placement.network_size != model.network_size()
        {
            return Err(Error::Shape(format!(
                "placement is for camera ({}, {}) / network ({}, {}), the model for ({}, {}) / ({}, {})",
                placement.camera_size.width,
                placement.camera_size.height,
                placement.network_size.width,
                placement.network_size.height,
                model.camera_size().width,
                model.camera_size().height,
                model.network_size().width,
                model.network_size().height
            )));
        }
        let photometric = Photometric::for_model(ctx, model)?;
        let place = Stage::new(
            ctx,
            "place",
            PLACE,
            "place",
            &[
                Slot::Uniform,
                Slot::Texture,
                Slot::Storage,
                Slot::Output(wgpu::TextureFormat::Rgba32Float),
            ],
        )?;
        let canvas = Stage::new(
            ctx,
            "canvas",
            CANVAS,
            "canvas",
            &[Slot::Uniform, Slot::Texture, Slot::Output(FRAME_FORMAT)],
        )?;
        let p = &placement;
        let Images {
            desired,
            network,
            output,
        } = Images::new(ctx, p);
        let fov: Vec<f32> = model
            .fov
            .data()
            .iter()
            .map(|&b| if b { 1.0 } else { 0.0 })
            .collect();
        let fov = storage(ctx, "fov mask", &fov);
        let place_params = uniform(ctx, "place params", &PlaceParams::zeroed());
        let canvas_params = uniform(
            ctx,
            "canvas params",
            &CanvasParams {
                projector: u2(p.projector_size),
                network: u2(p.network_size),
                origin: [p.canvas.x as u32, p.canvas.y as u32],
                size: [p.canvas.width as u32, p.canvas.height as u32],
            },
        );
        let photometric_groups = photometric.bind(ctx, &view(&desired), &view(&network));
        let canvas_group = canvas.bind(
            ctx,
            "canvas",
            &[
                canvas_params.as_entire_binding(),
                wgpu::BindingResource::TextureView(&view(&network)),
                wgpu::BindingResource::TextureView(&view(&output)),
            ],
        );
        Ok(Self {
            placement,
            place,
            place_params,
            fov,
            photometric,
            canvas,
            desired,
            network,
            output,
            photometric_groups,
            canvas_group,
            content: None,
        })
    }

    pub fn placement(&self) -> &Placement {
        &self.placement
    }

    /// The model's photometric stage (tests read its intermediate activations).
    pub fn photometric(&self) -> &Photometric {
        &self.photometric
    }

    /// The projector frame (rgba8unorm, projector pixels) the last dispatch wrote.
    pub fn output(&self) -> &wgpu::Texture {
        &self.output
    }

    /// Uploads a content frame (the only per-frame transfer to the GPU).
    pub fn upload(&mut self, ctx: &GpuContext, frame: &ContentFrame) -> Result<()> {
        if frame.width == 0 || frame.height == 0 {
            return Err(Error::Shape("empty content frame".into()));
        }
        let c = match self.content.take() {
            Some(c) if c.size == frame.size() => c,
            _ => self.make_content(ctx, frame.size()),
        };
        let c = self.content.insert(c);
        ctx.queue.write_texture(
            c.texture.as_image_copy(),
            &frame.rgba,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(frame.width as u32 * 4),
                rows_per_image: Some(frame.height as u32),
            },
            c.texture.size(),
        );
        Ok(())
    }

    fn make_content(&self, ctx: &GpuContext, size: ImageSize) -> Content {
        let p = &self.placement;
        ctx.queue.write_buffer(
            &self.place_params,
            0,
            bytemuck::bytes_of(&PlaceParams {
                camera: u2(p.camera_size),
                content: u2(size),
                area_origin: [p.area.x as u32, p.area.y as u32],
                area_size: [p.area.width as u32, p.area.height as u32],
                range: [p.range.low, p.range.high],
                margin: crate::fov::EDGE_MARGIN_PX as u32,
                _pad: 0,
            }),
        );
        let texture = image_texture(
            ctx,
            "content frame",
            size,
            wgpu::TextureFormat::Rgba8Unorm,
            wgpu::TextureUsages::COPY_DST,
        );
        let group = self.place.bind(
            ctx,
            "place",
            &[
                self.place_params.as_entire_binding(),
                wgpu::BindingResource::TextureView(&view(&texture)),
                self.fov.as_entire_binding(),
                wgpu::BindingResource::TextureView(&view(&self.desired)),
            ],
        );
        Content {
            size,
            texture,
            group,
        }
    }

    /// Records the three stages for the last uploaded frame (an error before any upload).
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<()> {
        self.encode_stages(enc, timestamps, &PassStage::ALL)
    }

    /// Records `stages` (in the order given) for the last uploaded frame, for timing one stage
    /// alone; each reads what the previous frame's stages left in the textures.
    pub fn encode_stages(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
        stages: &[PassStage],
    ) -> Result<()> {
        let content = self
            .content
            .as_ref()
            .ok_or_else(|| Error::Failed("compensation pass: no content frame uploaded".into()))?;
        let p = &self.placement;
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("compensation"),
            timestamp_writes: timestamps,
        });
        for stage in stages {
            match stage {
                PassStage::Place => self
                    .place
                    .dispatch(&mut pass, &content.group, p.camera_size),
                PassStage::Photometric => self
                    .photometric
                    .dispatch(&mut pass, &self.photometric_groups),
                PassStage::Canvas => {
                    self.canvas
                        .dispatch(&mut pass, &self.canvas_group, p.projector_size)
                }
            }
        }
        Ok(())
    }

    /// Uploads `frame`, runs the pass and submits it (no wait).
    pub fn run(&mut self, ctx: &GpuContext, frame: &ContentFrame) -> Result<()> {
        self.upload(ctx, frame)?;
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("compensation"),
            });
        self.encode(&mut enc, None)?;
        ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// The projector frame read back (values v/255), for the virtual rig and tests.
    pub fn read_output(&self, ctx: &GpuContext) -> Result<PrjImage> {
        read_rgba8(ctx, &self.output)
    }

    /// The projector frame the pass wrote, as its 8-bit RGBA bytes (projector pixels, row-major,
    /// no padding): what a media output encodes.
    pub fn read_output_rgba(&self, ctx: &GpuContext) -> Result<Vec<u8>> {
        ctx.read_texture(&self.output, 4)
    }

    /// The compensation image (network pixels, f32) read back, for tests.
    pub fn read_network(&self, ctx: &GpuContext) -> Result<NetImage> {
        read_rgba32f(ctx, &self.network)
    }

    /// The desired camera view (camera pixels, f32, FOV-masked) read back, for tests.
    pub fn read_desired(&self, ctx: &GpuContext) -> Result<crate::raster::CamImage> {
        read_rgba32f(ctx, &self.desired)
    }
}

/// The per-frame work the playback loop ([`crate::player`]) drives: a content frame in, the
/// display's picture out, left on the GPU for the screen to present, and read back where a
/// display or an output needs it on the CPU. One projector's [`CompensationPass`], or a set's
/// [`super::joint::SetPass`] (its projectors' pictures side by side).
pub trait FramePass {
    /// Uploads `frame` (content pixels, sRGB-encoded) and submits the pass (no wait).
    fn run_frame(&mut self, ctx: &GpuContext, frame: &ContentFrame) -> Result<()>;

    /// The picture of the frame last run, read back (projector pixels, values v/255; a set's
    /// projectors left to right, [`crate::device::side_by_side`]).
    fn read_frame(&self, ctx: &GpuContext) -> Result<PrjImage>;

    /// [`FramePass::read_frame`] as 8-bit RGBA bytes (row-major, no padding): what a media
    /// output encodes.
    fn read_frame_rgba(&self, ctx: &GpuContext) -> Result<Vec<u8>> {
        Ok(crate::pngio::to_rgba8(&self.read_frame(ctx)?))
    }
}

impl FramePass for CompensationPass {
    fn run_frame(&mut self, ctx: &GpuContext, frame: &ContentFrame) -> Result<()> {
        self.run(ctx, frame)
    }

    fn read_frame(&self, ctx: &GpuContext) -> Result<PrjImage> {
        self.read_output(ctx)
    }

    fn read_frame_rgba(&self, ctx: &GpuContext) -> Result<Vec<u8>> {
        self.read_output_rgba(ctx)
    }
}

/// An rgba8unorm texture as an f32 image (v/255, alpha dropped).
pub fn read_rgba8<S: Space>(ctx: &GpuContext, t: &wgpu::Texture) -> Result<Rgb<S>> {
    let bytes = ctx.read_texture(t, 4)?;
    let data = bytes
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]].map(|v| v as f32 / 255.0))
        .collect();
    Rgb::from_vec(t.width() as usize, t.height() as usize, data)
}

/// An rgba32float texture as an f32 image (alpha dropped).
pub fn read_rgba32f<S: Space>(ctx: &GpuContext, t: &wgpu::Texture) -> Result<Rgb<S>> {
    let bytes = ctx.read_texture(t, 16)?;
    let floats: &[f32] = bytemuck::try_cast_slice(&bytes)
        .map_err(|e| Error::Failed(format!("GPU read-back layout: {e}")))?;
    let data = floats
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    Rgb::from_vec(t.width() as usize, t.height() as usize, data)
}
