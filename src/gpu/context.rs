//! The GPU device: one wgpu instance, adapter, device and queue, created once per process.
//!
//! No adapter is a normal outcome on a machine without a GPU or a software Vulkan driver: it is
//! an [`Error::Gpu`] whose cause is a [`NoAdapter`] ([`is_no_adapter`] tells it apart), so
//! callers can skip or fall back; an adapter that exists but fails to open is another
//! [`Error::Gpu`]. Every wgpu failure keeps its cause.

use crate::error::{Error, Result};

/// How the backbone's wide layers (16 or more output channels: convolutions, and transposed
/// convolutions whose kernel is as wide as their stride, uncropped; the 3-channel layers run the
/// direct kernel) are computed on the GPU. The direct and the tiled kernel of a layer compute
/// the same sums in the same order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ConvKernels {
    /// `conv` (`tconv`): each invocation sums 4 pixels (1 pixel) × 16 channels straight from
    /// the activations. Few, long invocations: what a CPU driver (lavapipe) runs fastest (the
    /// 256² backbone 1.2–1.5× faster than with `tiled` convolutions there, in four runs).
    Direct,
    /// `conv_tiled` (`tconv_tiled`): each workgroup computes 64 pixels × 64 channels as a
    /// matrix product staged through workgroup memory: 4 to 16 times the invocations, for a
    /// GPU's many cores.
    Tiled,
    /// Each wide layer is timed with both kernels on this device when a stage is first built
    /// with its shape, and runs the faster: per wide layer, 2 rounds of each kernel, each
    /// round 2 untimed and 2 timed dispatches of the layer alone, each submitted and waited
    /// for (16 per layer, 144 for the backbone's 9 wide layers: an estimated 0.1 s from the
    /// per-layer times measured on an H100 and an H200, docs/bench/gpu-h100.md). Playback on
    /// the same GPU waits behind them. Each layer shape is timed once per device and process;
    /// later passes take the choice made then.
    Measured,
}

impl ConvKernels {
    /// The kernels for an adapter: direct on a CPU driver, measured on a GPU (no one kernel
    /// is fastest on every GPU and layer shape).
    pub fn for_adapter(info: &wgpu::AdapterInfo) -> Self {
        if info.device_type == wgpu::DeviceType::Cpu {
            Self::Direct
        } else {
            Self::Measured
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Direct => "direct",
            Self::Tiled => "tiled",
            Self::Measured => "measured",
        }
    }

    /// The entry points a wide layer may run with (`shaders/conv.wgsl`): a convolution's, or
    /// where `transposed`, a transposed convolution's whose kernel is as wide as its stride and
    /// which crops nothing.
    pub(super) fn wide_entries(self, transposed: bool) -> &'static [&'static str] {
        match (self, transposed) {
            (Self::Direct, false) => &["conv"],
            (Self::Tiled, false) => &["conv_tiled"],
            (Self::Measured, false) => &["conv", "conv_tiled"],
            (Self::Direct, true) => &["tconv"],
            (Self::Tiled, true) => &["tconv_tiled"],
            (Self::Measured, true) => &["tconv", "tconv_tiled"],
        }
    }
}

/// What a machine without a usable adapter is told.
const NO_ADAPTER_HINT: &str =
    "live compensation needs a GPU or a software Vulkan driver (Mesa lavapipe)";

/// An open GPU device. Cloning it clones wgpu's reference-counted handles: the clone is the same
/// device (a pass built on a clone runs on the original), e.g. for building a pass on another
/// thread.
#[derive(Clone)]
pub struct GpuContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// How CompenNet's wide layers run on this device: [`ConvKernels::for_adapter`]
    /// unless changed with [`Self::with_conv_kernels`].
    pub conv: ConvKernels,
    /// The layer shapes timed on this device ([`ConvKernels::Measured`]), shared by its clones.
    pub(crate) conv_timed: ConvTimings,
}

/// Kernel timings per layer shape on one device: the layer's uniform (`shaders/conv.wgsl`,
/// sizes and flags as 12 words) → each candidate entry point and its best time alone, ms. A
/// shape is timed once per process; later passes (a model swap, another display) reuse it.
pub(crate) type ConvTimings = std::sync::Arc<
    std::sync::Mutex<std::collections::HashMap<[u32; 12], Vec<(&'static str, f64)>>>,
>;

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GpuContext({})", self.describe())
    }
}

/// The cause of an [`Error::Gpu`] when wgpu found no adapter (none at all, or none that can
/// present to the projector window).
#[derive(Debug, thiserror::Error)]
#[error("no GPU adapter: {0}")]
pub struct NoAdapter(#[source] pub wgpu::RequestAdapterError);

/// Whether `err` says that there is no GPU adapter (rather than a GPU that failed).
pub fn is_no_adapter(err: &Error) -> bool {
    match err {
        Error::Gpu { source, .. } => source.is::<NoAdapter>(),
        _ => false,
    }
}

impl GpuContext {
    /// Opens the default adapter (backends from `WGPU_BACKEND`, e.g. `vulkan` or `gl`; the
    /// software Vulkan driver lavapipe counts as an adapter). No adapter: an [`Error::Gpu`] for
    /// which [`is_no_adapter`] holds.
    pub fn new() -> Result<Self> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Self::with_instance(instance, None)
    }

    /// Opens an adapter of `instance`, compatible with `surface` when given (the projector
    /// window).
    pub fn with_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Self> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| {
            let what = match surface {
                Some(_) => {
                    format!("no adapter can present to the projector window; {NO_ADAPTER_HINT}")
                }
                None => format!("no adapter; {NO_ADAPTER_HINT}"),
            };
            Error::gpu(what, NoAdapter(e))
        })?;
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
            Error::gpu(
                format!("adapter {} did not open a device", adapter.get_info().name),
                e,
            )
        })?;
        let conv = ConvKernels::for_adapter(&adapter.get_info());
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
            conv,
            conv_timed: ConvTimings::default(),
        })
    }

    /// The same device, building CompenNet's wide layers with `conv` (for benchmarks and
    /// tests; passes already built keep theirs).
    pub fn with_conv_kernels(&self, conv: ConvKernels) -> Self {
        Self {
            conv,
            ..self.clone()
        }
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
            .map_err(|e| Error::gpu("waiting for the GPU", e))
    }

    /// Compiles a WGSL module; a validation error is an [`Error::Gpu`] naming the shader.
    pub fn shader(&self, label: &str, source: &str) -> Result<wgpu::ShaderModule> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::gpu(format!("shader {label}"), e));
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
        let buffer = self.staging((padded * h) as u64);
        let mut enc = self.encoder("readback");
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
        self.map_read(&buffer, |view| {
            let mut out = Vec::with_capacity((row * h) as usize);
            for y in 0..h as usize {
                let start = y * padded as usize;
                out.extend_from_slice(&view[start..start + row as usize]);
            }
            Ok(out)
        })
    }

    /// Reads back a storage buffer (created with `COPY_SRC`) of f32 values.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer) -> Result<Vec<f32>> {
        let size = buffer.size();
        let staging = self.staging(size);
        let mut enc = self.encoder("readback");
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        self.map_read(&staging, |view| {
            Ok(bytemuck::try_cast_slice::<u8, f32>(view)
                .map_err(|e| Error::Failed(format!("GPU read-back layout: {e}")))?
                .to_vec())
        })
    }

    /// A command encoder.
    pub fn encoder(&self, label: &str) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
    }

    /// A buffer of `size` bytes to copy GPU data into and map for reading.
    fn staging(&self, size: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        })
    }

    /// Maps `buffer` (whose copy was submitted) for reading once the GPU is done, hands its bytes
    /// to `read`, and unmaps it.
    pub(crate) fn map_read<T>(
        &self,
        buffer: &wgpu::Buffer,
        read: impl FnOnce(&[u8]) -> Result<T>,
    ) -> Result<T> {
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| Error::gpu("GPU read-back was cancelled", e))?
            .map_err(|e| Error::gpu("GPU read-back", e))?;
        let out = {
            let view = buffer
                .get_mapped_range(..)
                .map_err(|e| Error::gpu("GPU read-back mapping", e))?;
            read(&view)
        };
        buffer.unmap();
        out
    }
}
