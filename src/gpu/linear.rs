//! The `linear` model's photometric stage on the GPU (`shaders/linear.wgsl`): the desired camera
//! view sampled through the baked grid, then the per-pixel affine colour model in linear light.
//! CPU reference: [`crate::linear::SimplifiedLinear::apply`].

use bytemuck::{Pod, Zeroable};

use super::GpuContext;
use super::kernel::{Slot, Stage, storage, uniform};
use crate::error::{Error, Result};
use crate::linear::SimplifiedLinear;
use crate::raster::ImageSize;

const SHADER: &str = concat!(
    include_str!("../../shaders/common.wgsl"),
    include_str!("../../shaders/linear.wgsl")
);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    camera: [u32; 2],
    network: [u32; 2],
    camera_gamma: [f32; 4],
    camera_inv_gamma: [f32; 4],
    projector_inv_gamma: [f32; 4],
}

/// A model's curves as the compensation shaders read them (xyz per channel, w unused): γc, 1/γc
/// and 1/γp, each 1/γ in f32 exactly as `Curves::projector_input` and the gamut map compute it.
pub(super) fn curve_params(c: &crate::linear::Curves) -> [[f32; 4]; 3] {
    let inv = |g: [f32; 3]| [1.0 / g[0], 1.0 / g[1], 1.0 / g[2], 0.0];
    let g = c.camera_gamma;
    [[g[0], g[1], g[2], 0.0], inv(g), inv(c.projector_gamma)]
}

/// The model's constants on the GPU and the compiled stage.
pub struct LinearStage {
    stage: Stage,
    params: wgpu::Buffer,
    grid: wgpu::Buffer,
    coeffs: wgpu::Buffer,
    network_size: ImageSize,
}

impl LinearStage {
    /// Uploads the grid (network pixels → normalised camera positions) and the per-pixel
    /// coefficients once; `camera_size` is the desired view's size in camera pixels.
    pub fn new(ctx: &GpuContext, model: &SimplifiedLinear, camera_size: ImageSize) -> Result<Self> {
        let ImageSize {
            width: nw,
            height: nh,
        } = model.grid.size();
        if (model.coeffs.width, model.coeffs.height) != (nw, nh) {
            return Err(Error::Shape(format!(
                "linear model: grid {nw}x{nh} but coefficients {}x{}",
                model.coeffs.width, model.coeffs.height
            )));
        }
        let [camera_gamma, camera_inv_gamma, projector_inv_gamma] = curve_params(&model.curves);
        let params = Params {
            camera: [camera_size.width as u32, camera_size.height as u32],
            network: [nw as u32, nh as u32],
            camera_gamma,
            camera_inv_gamma,
            projector_inv_gamma,
        };
        let grid: Vec<f32> = model.grid.data().iter().flatten().copied().collect();
        let coeffs: Vec<f32> = model.coeffs.data.iter().flatten().copied().collect();
        Ok(Self {
            stage: Stage::new(
                ctx,
                "linear",
                SHADER,
                "linear",
                &[
                    Slot::Uniform,
                    Slot::Texture,
                    Slot::Storage,
                    Slot::Storage,
                    Slot::Output(wgpu::TextureFormat::Rgba32Float),
                ],
            )?,
            params: uniform(ctx, "linear params", &params),
            grid: storage(ctx, "linear grid", &grid),
            coeffs: storage(ctx, "linear coefficients", &coeffs),
            network_size: ImageSize::new(nw, nh),
        })
    }

    /// The bind group reading the desired view `desired` and writing the network image `network`.
    pub fn bind(
        &self,
        ctx: &GpuContext,
        desired: &wgpu::TextureView,
        network: &wgpu::TextureView,
    ) -> wgpu::BindGroup {
        self.stage.bind(
            ctx,
            "linear",
            &[
                self.params.as_entire_binding(),
                wgpu::BindingResource::TextureView(desired),
                self.grid.as_entire_binding(),
                self.coeffs.as_entire_binding(),
                wgpu::BindingResource::TextureView(network),
            ],
        )
    }

    pub fn dispatch(&self, pass: &mut wgpu::ComputePass<'_>, group: &wgpu::BindGroup) {
        self.stage.dispatch(pass, group, self.network_size);
    }
}
