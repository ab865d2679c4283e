//! The benchmarks' GPU measurements (`compend bench-gpu`, a build with the `benches` feature):
//! per-frame GPU time of the compensation pass against a plain texture copy of the projector
//! frame's size measured in the same run (the memory-bandwidth floor of anything that writes a
//! projector frame), each stage alone, each CompenNet layer alone.
//!
//! Each measurement encodes one frame's work, submits it and waits for the GPU; the median over
//! `iters` runs (after warm-up runs, which also JIT-compile shaders on software drivers) is
//! reported. Where the adapter has timestamp queries inside encoders, the GPU's own timestamps
//! around the work are reported too. Content upload is not part of the pass time (it is a queue
//! write that overlaps with the previous frame).

use super::GpuContext;
pub use super::live::time_pass;
use super::pass::CompensationPass;
pub use super::timing::{Timing, time_work};
use crate::error::Result;
use crate::playback::ContentFrame;
use crate::raster::ImageSize;

/// A plain copy of a projector-sized rgba8 texture into another (the bandwidth floor).
pub fn time_copy(
    ctx: &GpuContext,
    ImageSize {
        width: w,
        height: h,
    }: ImageSize,
    warmup: usize,
    iters: usize,
) -> Result<Timing> {
    let make = |label| {
        ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: w as u32,
                height: h as u32,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: super::FRAME_FORMAT,
            usage: wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        })
    };
    let (src, dst) = (make("copy source"), make("copy target"));
    time_work(ctx, warmup, iters, |enc| {
        enc.copy_texture_to_texture(src.as_image_copy(), dst.as_image_copy(), src.size());
        Ok(())
    })
}

/// Each stage of a pass alone (after one full frame on `content`): (stage, timing).
pub fn time_stages(
    ctx: &GpuContext,
    pass: &mut CompensationPass,
    content: &ContentFrame,
    warmup: usize,
    iters: usize,
) -> Result<Vec<(&'static str, Timing)>> {
    pass.run(ctx, content)?;
    ctx.wait()?;
    let pass = &*pass;
    super::PassStage::ALL
        .into_iter()
        .map(|stage| {
            let t = time_work(ctx, warmup, iters, |enc| {
                pass.encode_stages(enc, None, &[stage])
            })?;
            Ok((stage.name(), t))
        })
        .collect()
}

/// Per-layer times of a CompenNet pass (after one full frame on `content`): (layer, timing),
/// each layer dispatched alone; empty for other models.
pub fn time_compennet_layers(
    ctx: &GpuContext,
    pass: &mut CompensationPass,
    content: &ContentFrame,
    warmup: usize,
    iters: usize,
) -> Result<Vec<(&'static str, Timing)>> {
    pass.run(ctx, content)?;
    ctx.wait()?;
    let super::Photometric::CompenNet(stage) = pass.photometric() else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for (i, name) in stage.layer_names().into_iter().enumerate() {
        let t = time_work(ctx, warmup, iters, |enc| {
            let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(name),
                timestamp_writes: None,
            });
            stage.dispatch_layer(&mut cp, i);
            Ok(())
        })?;
        out.push((name, t));
    }
    Ok(out)
}
