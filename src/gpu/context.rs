//! The GPU device: one wgpu instance, adapter, device and queue, created once per process.
//!
//! No adapter is a normal outcome on a machine without a GPU or a software Vulkan driver:
//! [`GpuContext::new`] reports it as `Ok(None)` with the reason, so callers can fall back to the
//! CPU or skip; a device that exists but fails is an error.

use crate::error::{Error, Result};

/// An open GPU device.
pub struct GpuContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GpuContext({})", self.describe())
    }
}

/// Why there is no GPU context.
#[derive(Clone, Debug)]
pub struct NoAdapter(pub String);

impl std::fmt::Display for NoAdapter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl GpuContext {
    /// Opens the default adapter (backends from `WGPU_BACKEND`, e.g. `vulkan` or `gl`; the
    /// software Vulkan driver lavapipe counts as an adapter). `Ok(Err(reason))` when there is none.
    pub fn new() -> Result<std::result::Result<Self, NoAdapter>> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Self::with_instance(instance, None)
    }

    /// Opens an adapter of `instance`, compatible with `surface` when given (the projector
    /// window).
    pub fn with_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<std::result::Result<Self, NoAdapter>> {
        let adapter =
            match pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: surface,
                ..Default::default()
            })) {
                Ok(a) => a,
                Err(e) => return Ok(Err(NoAdapter(format!("no GPU adapter: {e}")))),
            };
        // Timestamps help the benchmark when the adapter has them; nothing else needs a feature.
        let wanted =
            wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS;
        let features = adapter.features() & wanted;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("compend"),
            required_features: features,
            required_limits: wgpu::Limits::default().using_resolution(adapter.limits()),
            ..Default::default()
        }))
        .map_err(|e| {
            Error::Failed(format!(
                "GPU adapter {} did not open a device: {e}",
                adapter.get_info().name
            ))
        })?;
        Ok(Ok(Self {
            instance,
            adapter,
            device,
            queue,
        }))
    }

    /// "name (backend, device type)".
    pub fn describe(&self) -> String {
        let i = self.adapter.get_info();
        format!("{} ({:?}, {:?})", i.name, i.backend, i.device_type)
    }

    /// Waits until the GPU has finished all submitted work.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Failed(format!("GPU wait failed: {e}")))
    }

    /// Compiles a WGSL module, turning validation errors into [`Error::Failed`].
    pub fn shader(&self, label: &str, source: &str) -> Result<wgpu::ShaderModule> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Failed(format!("shader {label}: {e}")));
        }
        Ok(module)
    }

    /// Reads back an RGBA texture of `format` rgba8unorm (4 bytes per texel) or rgba32float
    /// (16 bytes per texel) as tightly packed rows.
    pub fn read_texture(&self, texture: &wgpu::Texture, bytes_per_texel: u32) -> Result<Vec<u8>> {
        let (w, h) = (texture.width(), texture.height());
        let row = w * bytes_per_texel;
        let padded =
            row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: (padded * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        enc.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(h),
                },
            },
            texture.size(),
        );
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| Error::Failed("GPU read-back was cancelled".into()))?
            .map_err(|e| Error::Failed(format!("GPU read-back failed: {e}")))?;
        let mut out = Vec::with_capacity((row * h) as usize);
        {
            let view = buffer
                .get_mapped_range(..)
                .map_err(|e| Error::Failed(format!("GPU read-back mapping: {e}")))?;
            for y in 0..h as usize {
                let start = y * padded as usize;
                out.extend_from_slice(&view[start..start + row as usize]);
            }
        }
        buffer.unmap();
        Ok(out)
    }

    /// Reads back a storage buffer (created with `COPY_SRC`) of f32 values.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer) -> Result<Vec<f32>> {
        let size = buffer.size();
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| Error::Failed("GPU read-back was cancelled".into()))?
            .map_err(|e| Error::Failed(format!("GPU read-back failed: {e}")))?;
        let out = {
            let view = staging
                .get_mapped_range(..)
                .map_err(|e| Error::Failed(format!("GPU read-back mapping: {e}")))?;
            bytemuck::try_cast_slice::<u8, f32>(&view)
                .map_err(|e| Error::Failed(format!("GPU read-back layout: {e}")))?
                .to_vec()
        };
        staging.unmap();
        Ok(out)
    }
}
