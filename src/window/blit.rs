//! The blit: a fullscreen triangle drawing a projector frame texture onto the window's surface
//! pixel for pixel (`shaders/blit.wgsl`, textureLoad per pixel), or stretched over the surface
//! bilinearly (a set's projector image on its network lattice, onto its monitor).

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
    /// [`Fit::Stretch`]: the surface's size in pixels (vec4 of f32: width, height, 0, 0).
    surface_size: Option<wgpu::Buffer>,
}

/// How a frame meets the surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Fit {
    /// Pixel for pixel from the top-left corner; what the frame does not cover is black.
    Exact,
    /// Stretched over the whole surface, bilinear with half-pixel centres
    /// (`resize::resize_bilinear` is its CPU reference); equal sizes copy exactly.
    Stretch,
}

impl Blit {
    /// The pipeline drawing into surfaces of `format`.
    pub(super) fn new(ctx: &GpuContext, format: wgpu::TextureFormat, fit: Fit) -> Result<Self> {
        let module = ctx.shader("blit", BLIT)?;
        let mut entries = vec![wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        }];
        let surface_size = (fit == Fit::Stretch).then(|| {
            entries.push(wgpu::BindGroupLayoutEntry {
                binding: 1,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            });
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("blit surface size"),
                size: 16,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("blit"),
                entries: &entries,
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
                    entry_point: Some(match fit {
                        Fit::Exact => "fs",
                        Fit::Stretch => "fs_stretch",
                    }),
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
            surface_size,
        })
    }

    /// The bind group reading `frame`, made when the frame texture changes.
    fn bind(&mut self, ctx: &GpuContext, frame: &wgpu::Texture) -> &wgpu::BindGroup {
        let bound = match self.bound.take() {
            Some((t, group)) if t == *frame => (t, group),
            _ => {
                let view = frame.create_view(&wgpu::TextureViewDescriptor::default());
                let mut entries = vec![wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                }];
                if let Some(b) = &self.surface_size {
                    entries.push(wgpu::BindGroupEntry {
                        binding: 1,
                        resource: b.as_entire_binding(),
                    });
                }
                let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("blit"),
                    layout: &self.layout,
                    entries: &entries,
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
        if let Some(b) = &self.surface_size {
            let size = target.texture().size();
            let v = [size.width as f32, size.height as f32, 0.0, 0.0];
            ctx.queue.write_buffer(b, 0, bytemuck::cast_slice(&v));
        }
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
