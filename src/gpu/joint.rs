//! The joint pass of a set of projectors (`shaders/joint.wgsl`, after `shaders/common.wgsl`):
//! from one desired camera view, every projector's image, each compensated for the surface and
//! for the others' light, one dispatch per projector on one device. CPU reference:
//! [`crate::joint::JointModel::apply`].

use bytemuck::{Pod, Zeroable};

use super::GpuContext;
use super::kernel::{Slot, Stage, image_texture, storage, uniform, view};
use super::pass::{FramePass, read_rgba32f};
use crate::error::{Error, Result};
use crate::fov::DisplayRange;
use crate::joint::{JointModel, MAX_PROJECTORS, SLOT_FLOATS};
use crate::playback::{ContentFrame, place_on_canvas};
use crate::raster::{CamImage, ImageSize, NetImage, PrjImage, Rect, Unspecified};

const SHADER: &str = concat!(
    include_str!("../../shaders/common.wgsl"),
    include_str!("../../shaders/joint.wgsl")
);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    camera: [u32; 2],
    network: [u32; 2],
    set_size: u32,
    own: u32,
    pad: [u32; 2],
    camera_gamma: [f32; 4],
    camera_inv_gamma: [f32; 4],
    projector_inv_gamma: [f32; 4],
    /// Per projector: lattice width, height, 0, 0.
    lattice: [[u32; 4]; MAX_PROJECTORS],
}

/// One projector's stage: its constants and its output.
struct Output {
    group: wgpu::BindGroup,
    texture: wgpu::Texture,
    size: ImageSize,
}

/// The joint pass of a set: every projector's constants uploaded once, a desired view in, each
/// projector's image (its network lattice, projector input values, rgba32float) out.
pub struct JointPass {
    stage: Stage,
    desired: wgpu::Texture,
    outputs: Vec<Output>,
    camera: ImageSize,
}

impl JointPass {
    /// Uploads the joint model's grids, slots and every projector's coefficients.
    pub fn new(ctx: &GpuContext, joint: &JointModel) -> Result<Self> {
        let n = joint.projectors();
        let camera = joint.camera_size();
        let stage = Stage::new(
            ctx,
            "joint",
            SHADER,
            "joint",
            &[
                Slot::Uniform,
                Slot::Texture,
                Slot::Storage,
                Slot::Storage,
                Slot::Storage,
                Slot::Storage,
                Slot::Storage,
                Slot::Storage,
                Slot::Output(wgpu::TextureFormat::Rgba32Float),
            ],
        )?;
        let models: Vec<_> = (0..n)
            .map(|k| {
                joint
                    .model(k)
                    .ok_or_else(|| Error::Failed(format!("joint model: no projector {k}")))
            })
            .collect::<Result<_>>()?;
        let mut lattice = [[0u32; 4]; MAX_PROJECTORS];
        // One buffer per projector (a storage binding holds at most 128 MiB); a set of fewer
        // than MAX_PROJECTORS binds an empty one in the others' places.
        let mut coeffs: Vec<wgpu::Buffer> = Vec::with_capacity(MAX_PROJECTORS);
        for (k, m) in models.iter().enumerate() {
            lattice[k] = [m.coeffs.width as u32, m.coeffs.height as u32, 0, 0];
            let data: Vec<f32> = m.coeffs.data.iter().flatten().copied().collect();
            coeffs.push(storage(ctx, "joint coefficients", &data));
        }
        while coeffs.len() < MAX_PROJECTORS {
            coeffs.push(storage(ctx, "joint coefficients (none)", &[]));
        }
        let desired = image_texture(
            ctx,
            "joint desired",
            camera,
            wgpu::TextureFormat::Rgba32Float,
            wgpu::TextureUsages::COPY_DST,
        );
        let desired_view = view(&desired);
        let mut outputs = Vec::with_capacity(n);
        for (k, m) in models.iter().enumerate() {
            let size = m.grid.size();
            if (m.coeffs.width, m.coeffs.height) != (size.width, size.height) {
                return Err(Error::Shape(format!(
                    "projector {}: grid {size} but coefficients {}x{}",
                    k + 1,
                    m.coeffs.width,
                    m.coeffs.height
                )));
            }
            let slots = joint
                .slots(k)
                .ok_or_else(|| Error::Failed(format!("joint model: no slots of {k}")))?;
            let mut table = Vec::with_capacity(slots.len() * n * SLOT_FLOATS);
            for px in slots {
                for slot in &px[..n] {
                    match slot {
                        Some(s) => table.extend([s.at[0], s.at[1], s.share]),
                        None => table.extend([-1.0, -1.0, 0.0]),
                    }
                }
            }
            let [camera_gamma, camera_inv_gamma, projector_inv_gamma] =
                super::linear::curve_params(&m.curves);
            let params = Params {
                camera: [camera.width as u32, camera.height as u32],
                network: [size.width as u32, size.height as u32],
                set_size: n as u32,
                own: k as u32,
                pad: [0; 2],
                camera_gamma,
                camera_inv_gamma,
                projector_inv_gamma,
                lattice,
            };
            let params = uniform(ctx, "joint params", &params);
            let grid: Vec<f32> = m.grid.data().iter().flatten().copied().collect();
            let grid = storage(ctx, "joint grid", &grid);
            let slots = storage(ctx, "joint slots", &table);
            let texture = image_texture(
                ctx,
                "joint output",
                size,
                wgpu::TextureFormat::Rgba32Float,
                wgpu::TextureUsages::STORAGE_BINDING,
            );
            let group = stage.bind(
                ctx,
                "joint",
                &[
                    params.as_entire_binding(),
                    wgpu::BindingResource::TextureView(&desired_view),
                    grid.as_entire_binding(),
                    slots.as_entire_binding(),
                    coeffs[0].as_entire_binding(),
                    coeffs[1].as_entire_binding(),
                    coeffs[2].as_entire_binding(),
                    coeffs[3].as_entire_binding(),
                    wgpu::BindingResource::TextureView(&view(&texture)),
                ],
            );
            outputs.push(Output {
                group,
                texture,
                size,
            });
        }
        Ok(JointPass {
            stage,
            desired,
            outputs,
            camera,
        })
    }

    /// Uploads the desired view (camera pixels, encoded values).
    pub fn upload(&self, ctx: &GpuContext, desired: &CamImage) -> Result<()> {
        if desired.size() != self.camera {
            return Err(Error::Shape(format!(
                "a {} desired view for a joint pass of a {} camera",
                desired.size(),
                self.camera
            )));
        }
        let rgba: Vec<f32> = desired
            .data()
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 1.0])
            .collect();
        ctx.queue.write_texture(
            self.desired.as_image_copy(),
            bytemuck::cast_slice(&rgba),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(self.camera.width as u32 * 16),
                rows_per_image: Some(self.camera.height as u32),
            },
            self.desired.size(),
        );
        Ok(())
    }

    /// Records every projector's dispatch for the last uploaded view.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("joint"),
            timestamp_writes: timestamps,
        });
        for o in &self.outputs {
            self.stage.dispatch(&mut pass, &o.group, o.size);
        }
    }

    /// Uploads `desired`, runs every projector's dispatch and submits them (no wait).
    pub fn run(&self, ctx: &GpuContext, desired: &CamImage) -> Result<()> {
        self.upload(ctx, desired)?;
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("joint"),
            });
        self.encode(&mut enc, None);
        ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Every projector's image (its network lattice, projector input values), read back.
    pub fn read(&self, ctx: &GpuContext) -> Result<Vec<NetImage>> {
        self.outputs
            .iter()
            .map(|o| read_rgba32f(ctx, &o.texture))
            .collect()
    }

    /// The projectors' output textures (rgba32float, each its lattice's size), in set order.
    pub fn outputs(&self) -> Vec<&wgpu::Texture> {
        self.outputs.iter().map(|o| &o.texture).collect()
    }
}

/// A set's joint pass fed by content frames, for the playback loop: each frame's values mapped
/// into the set's display range and placed in its displayable area (camera pixels,
/// [`crate::fov::place_in_area`]), then the joint pass run on that desired view. The projectors'
/// images stay on the GPU for windows to present ([`SetPass::outputs`]); read back, each is
/// stretched over its projector's canvas and the canvases sit side by side.
pub struct SetPass {
    pass: JointPass,
    range: DisplayRange,
    /// The set's displayable area (camera pixels).
    area: Rect,
    /// Each projector's canvas (projector pixels).
    canvas: ImageSize,
    /// The desired view of the frame last run (camera pixels, encoded values).
    desired: Option<CamImage>,
}

impl SetPass {
    /// The pass of `joint` with content mapped into `range` and placed in `area` (camera
    /// pixels), each projector's image read back on a `canvas` (projector pixels).
    pub fn new(
        ctx: &GpuContext,
        joint: &JointModel,
        (range, area): (DisplayRange, Rect),
        canvas: ImageSize,
    ) -> Result<Self> {
        Ok(Self {
            pass: JointPass::new(ctx, joint)?,
            range,
            area,
            canvas,
            desired: None,
        })
    }

    /// The projectors' output textures (rgba32float, each its lattice's size), in set order.
    pub fn outputs(&self) -> Vec<&wgpu::Texture> {
        self.pass.outputs()
    }

    /// The desired view of the frame last run (camera pixels, encoded values) and the area it
    /// fills; `None` before the first frame.
    pub fn desired(&self) -> Option<(&CamImage, Rect)> {
        self.desired.as_ref().map(|d| (d, self.area))
    }

    /// Each projector's image of the frame last run on its canvas (projector pixels), in set
    /// order.
    pub fn canvases(&self, ctx: &GpuContext) -> Result<Vec<PrjImage>> {
        self.pass
            .read(ctx)?
            .iter()
            .map(|net| place_on_canvas(net, Rect::covering(self.canvas), self.canvas))
            .collect()
    }
}

impl FramePass for SetPass {
    fn run_frame(&mut self, ctx: &GpuContext, frame: &ContentFrame) -> Result<()> {
        let img: crate::raster::Rgb<Unspecified> = frame.to_image();
        let camera = self.pass.camera;
        let desired = crate::fov::place_in_area(&self.range.apply(&img), self.area, camera)?;
        self.pass.run(ctx, &desired)?;
        self.desired = Some(desired);
        Ok(())
    }

    fn read_frame(&self, ctx: &GpuContext) -> Result<PrjImage> {
        Ok(crate::device::side_by_side(&self.canvases(ctx)?))
    }
}
