//! The residual rungs' photometric stage on the GPU (`compennet++-res`, `compennet++-res-full`):
//! the `linear` stage into an image on the linear model's lattice, the CompenNet stage (its
//! residual tail) into the correction on its network, then `shaders/residual.wgsl` adds the
//! correction stretched over the lattice and clamps. CPU reference:
//! [`crate::model::add_correction`] on [`crate::model::Model::infer`]'s two parts.

use bytemuck::{Pod, Zeroable};

use super::GpuContext;
use super::compennet::CompenNetStage;
use super::kernel::{Slot, Stage, image_texture, uniform};
use super::linear::LinearStage;
use crate::error::Result;
use crate::linear::SimplifiedLinear;
use crate::nn::compennetpp::SimplifiedCompenNet;
use crate::raster::ImageSize;

const SHADER: &str = include_str!("../../shaders/residual.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    lattice: [u32; 2],
    coarse: [u32; 2],
}

/// The two stages, the images between them and the adding stage.
pub struct ResidualStage {
    linear: LinearStage,
    correction: CompenNetStage,
    add: Stage,
    params: wgpu::Buffer,
    /// `linear`'s compensation image: rgba32float, network pixels on its lattice.
    linear_image: wgpu::Texture,
    /// The correction: rgba32float (signed), network pixels of the coarser network.
    correction_image: wgpu::Texture,
    lattice: ImageSize,
}

impl ResidualStage {
    /// Uploads both models' constants once; `camera_size` is the desired view's size in camera
    /// pixels.
    pub fn new(
        ctx: &GpuContext,
        base: &SimplifiedLinear,
        correction: &SimplifiedCompenNet,
        camera_size: ImageSize,
    ) -> Result<Self> {
        let linear = LinearStage::new(ctx, base, camera_size)?;
        let correction = CompenNetStage::new(ctx, correction, camera_size)?;
        let lattice = base.grid.size();
        let coarse = correction.network_size();
        let f32x4 = wgpu::TextureFormat::Rgba32Float;
        let st = wgpu::TextureUsages::STORAGE_BINDING;
        Ok(Self {
            add: Stage::new(
                ctx,
                "residual",
                SHADER,
                "residual",
                &[
                    Slot::Uniform,
                    Slot::Texture,
                    Slot::Texture,
                    Slot::Output(f32x4),
                ],
            )?,
            params: uniform(
                ctx,
                "residual params",
                &Params {
                    lattice: [lattice.width as u32, lattice.height as u32],
                    coarse: [coarse.width as u32, coarse.height as u32],
                },
            ),
            linear_image: image_texture(ctx, "linear image", lattice, f32x4, st),
            correction_image: image_texture(ctx, "correction", coarse, f32x4, st),
            linear,
            correction,
            lattice,
        })
    }

    /// The bind groups reading the desired view `desired` and writing the network image
    /// `network` (the lattice's size): [linear, the CompenNet stage's…, add].
    pub fn bind(
        &self,
        ctx: &GpuContext,
        desired: &wgpu::TextureView,
        network: &wgpu::TextureView,
    ) -> Vec<wgpu::BindGroup> {
        let view = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
        let (linear_view, correction_view) =
            (view(&self.linear_image), view(&self.correction_image));
        let mut groups = vec![self.linear.bind(ctx, desired, &linear_view)];
        groups.extend(self.correction.bind(ctx, desired, &correction_view));
        groups.push(self.add.bind(
            ctx,
            "residual",
            &[
                self.params.as_entire_binding(),
                wgpu::BindingResource::TextureView(&linear_view),
                wgpu::BindingResource::TextureView(&correction_view),
                wgpu::BindingResource::TextureView(network),
            ],
        ));
        groups
    }

    /// Records linear, the correction network and the addition, in that order.
    pub fn dispatch(&self, pass: &mut wgpu::ComputePass<'_>, groups: &[wgpu::BindGroup]) {
        let [linear, correction @ .., add] = groups else {
            // bind() always returns at least the linear and the adding group.
            return;
        };
        self.linear.dispatch(pass, linear);
        self.correction.dispatch(pass, correction);
        self.add.dispatch(pass, add, self.lattice);
    }
}
