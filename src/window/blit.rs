//! The blit: a fullscreen triangle drawing a projector frame texture onto the window's surface
//! pixel for pixel (`shaders/blit.wgsl`, textureLoad per pixel).

use crate::error::Result;
use crate::gpu::GpuContext;

const BLIT: &str = include_str!("../../shaders/blit.wgsl");

/// The blit: a fullscreen triangle drawing a projector frame texture onto the surface pixel for
/// pixel (`shaders/blit.wgsl`).
pub(super) struct Blit {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    /// Bind group of the texture presented last (the pass output, reused every frame).
    bound: Option<(wgpu::Texture, wgpu::BindGroup)>,
}

impl Blit {
    /// The pipeline drawing into surfaces of `format`.
    pub(super) fn new(ctx: &GpuContext, format: wgpu::TextureFormat) -> Result<Self> {
        let module = ctx.shader("blit", BLIT)?;
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("blit"),
                entries: &[wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                }],
            });
        let pipeline_layout = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("blit"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let pipeline = ctx
            .device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("blit"),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            });
        Ok(Self {
            pipeline,
            layout,
            bound: None,
        })
    }

    /// The bind group reading `frame`, made when the frame texture changes.
    fn bind(&mut self, ctx: &GpuContext, frame: &wgpu::Texture) -> &wgpu::BindGroup {
        let bound = match self.bound.take() {
            Some((t, group)) if t == *frame => (t, group),
            _ => {
                let view = frame.create_view(&wgpu::TextureViewDescriptor::default());
                let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("blit"),
                    layout: &self.layout,
                    entries: &[wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&view),
                    }],
                });
                (frame.clone(), group)
            }
        };
        &self.bound.insert(bound).1
    }

    /// Records drawing `frame` onto `target`.
    pub(super) fn draw(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        frame: &wgpu::Texture,
        target: &wgpu::TextureView,
    ) {
        let group = self.bind(ctx, frame).clone();
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("present"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            ..Default::default()
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.draw(0..3, 0..1);
    }
}
