//! Small helpers shared by the compute stages: explicit bind-group layouts (intermediate images
//! are rgba32float, which is not filterable, so auto-derived layouts would not do), textures,
//! uniform and storage buffers, and one compute stage = pipeline + layout.

use wgpu::util::DeviceExt;

use super::GpuContext;
use crate::error::Result;
use crate::raster::ImageSize;

/// What a binding of a compute stage is.
#[derive(Clone, Copy, Debug)]
pub enum Slot {
    Uniform,
    /// Read-only storage buffer.
    Storage,
    /// Read-write storage buffer (intermediate activations).
    StorageRw,
    /// A texture read with textureLoad (`texture_2d<f32>`, not filtered).
    Texture,
    /// A write-only storage texture of this format.
    Output(wgpu::TextureFormat),
}

/// A compiled compute stage.
pub struct Stage {
    pub layout: wgpu::BindGroupLayout,
    pub pipeline: wgpu::ComputePipeline,
    pub workgroup: (u32, u32),
}

impl Stage {
    /// Compiles `entry` of `source` with bindings `slots` (binding i = slots\[i\], group 0).
    pub fn new(
        ctx: &GpuContext,
        label: &str,
        source: &str,
        entry: &str,
        slots: &[Slot],
    ) -> Result<Self> {
        Self::with_constants(ctx, label, source, entry, slots, &[])
    }

    /// [`Stage::new`] with values for the shader's pipeline-overridable constants (`override`).
    pub fn with_constants(
        ctx: &GpuContext,
        label: &str,
        source: &str,
        entry: &str,
        slots: &[Slot],
        constants: &[(&str, f64)],
    ) -> Result<Self> {
        let module = ctx.shader(label, source)?;
        let entries: Vec<wgpu::BindGroupLayoutEntry> = slots
            .iter()
            .enumerate()
            .map(|(i, s)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: match *s {
                    Slot::Uniform => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Slot::Storage => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Slot::StorageRw => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: false },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Slot::Texture => wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    Slot::Output(format) => wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                },
                count: None,
            })
            .collect();
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            });
        let pipeline_layout = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let pipeline = ctx
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    ..Default::default()
                },
                cache: None,
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(crate::Error::gpu(format!("compute stage {label}"), e));
        }
        Ok(Self {
            layout,
            pipeline,
            workgroup: (8, 8),
        })
    }

    /// A bind group with `resources` in binding order.
    pub fn bind(
        &self,
        ctx: &GpuContext,
        label: &str,
        resources: &[wgpu::BindingResource<'_>],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = resources
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// Records one dispatch covering `size` (width, height) invocations.
    pub fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        group: &wgpu::BindGroup,
        size: ImageSize,
    ) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(
            (size.width as u32).div_ceil(self.workgroup.0),
            (size.height as u32).div_ceil(self.workgroup.1),
            1,
        );
    }

    /// Records one dispatch of `groups` workgroups (x, y, z).
    pub fn dispatch_groups(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        group: &wgpu::BindGroup,
        (x, y, z): (u32, u32, u32),
    ) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(x, y, z);
    }
}

/// A 2-D texture of `format` usable as a stage input and output (and copied from).
pub fn image_texture(
    ctx: &GpuContext,
    label: &str,
    size: ImageSize,
    format: wgpu::TextureFormat,
    extra: wgpu::TextureUsages,
) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: (size.width as u32).max(1),
            height: (size.height as u32).max(1),
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_SRC | extra,
        view_formats: &[],
    })
}

pub fn view(t: &wgpu::Texture) -> wgpu::TextureView {
    t.create_view(&wgpu::TextureViewDescriptor::default())
}

pub fn uniform<T: bytemuck::Pod>(ctx: &GpuContext, label: &str, value: &T) -> wgpu::Buffer {
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
}

/// A zero-filled read-write storage buffer of `len` f32 values (at least one), also copyable
/// from (tests read intermediate activations back).
pub fn scratch(ctx: &GpuContext, label: &str, len: usize) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: 4 * len.max(1) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

pub fn storage(ctx: &GpuContext, label: &str, data: &[f32]) -> wgpu::Buffer {
    // A zero-length storage binding is invalid: keep at least one value.
    let data: &[f32] = if data.is_empty() { &[0.0] } else { data };
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(data),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        })
}
